"""endopipe's domain stages.

cv2 is imported here, first, on purpose: importing pycolmap before cv2 makes `cv2.imwrite` of a
PNG abort the process (a zlib/libpng clash). Every entry point passes through this package.
"""

import cv2  # noqa: F401  (must precede any pycolmap import)
