"""endopipe's domain stages.

Two side effects of importing pycolmap are undone here, the one place every entry point passes
through, for any later `import pycolmap`:
- pycolmap imported before cv2 makes `cv2.imwrite` of a PNG abort the process (a zlib/libpng
  clash): cv2 is imported first. It is not imported here: `endopipe --help` and `status` stay
  fast.
- pycolmap installs glog's failure handler for SIGTERM, which prints a native stack trace and
  kills the process before Python sees the signal: SIGTERM's disposition is put back as it was
  (the CLI's handler, which stops a run as Ctrl-C does, or the default).
"""

import importlib.abc
import importlib.machinery
import signal
import sys
import threading
from types import ModuleType


class _PycolmapImport(importlib.abc.MetaPathFinder):
    """Imports cv2 before pycolmap, and restores SIGTERM's handler once pycolmap has loaded."""

    def find_spec(
        self, name: str, path: object = None, target: object = None
    ) -> importlib.machinery.ModuleSpec | None:
        if name != "pycolmap":
            return None
        if "cv2" not in sys.modules:
            import cv2  # noqa: F401
        spec = importlib.machinery.PathFinder.find_spec(name, path)  # type: ignore[arg-type]
        if spec is None or spec.loader is None:
            return spec
        spec.loader = _KeepSigterm(spec.loader)
        return spec


class _KeepSigterm(importlib.abc.Loader):
    """The module's own loader, with SIGTERM's Python-level disposition re-applied after it."""

    def __init__(self, loader: importlib.abc.Loader) -> None:
        self.loader = loader

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType | None:
        return self.loader.create_module(spec)

    def exec_module(self, module: ModuleType) -> None:
        before = signal.getsignal(signal.SIGTERM)
        self.loader.exec_module(module)
        if threading.current_thread() is threading.main_thread() and before is not None:
            signal.signal(signal.SIGTERM, before)


if not any(isinstance(f, _PycolmapImport) for f in sys.meta_path):
    sys.meta_path.insert(0, _PycolmapImport())
