"""endopipe's domain stages.

Importing pycolmap before cv2 makes `cv2.imwrite` of a PNG abort the process (a zlib/libpng
clash). Every entry point passes through this package, which makes any later `import pycolmap`
import cv2 first. It does not import cv2 itself: `endopipe --help` and `status` stay fast.
"""

import importlib.abc
import sys


class _Cv2BeforePycolmap(importlib.abc.MetaPathFinder):
    """Imports cv2 when pycolmap is about to be imported, then lets the usual finders work."""

    def find_spec(self, name: str, path: object = None, target: object = None) -> None:
        if name == "pycolmap" and "cv2" not in sys.modules:
            import cv2  # noqa: F401

        return None


if not any(isinstance(f, _Cv2BeforePycolmap) for f in sys.meta_path):
    sys.meta_path.insert(0, _Cv2BeforePycolmap())
