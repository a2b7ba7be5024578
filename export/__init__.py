"""A processed case in other tools' formats (nerfstudio, colmap, endonerf, ply): one module
per format over the shared case loading of `case`; `formats.export_case` picks the format.
Each format's module says what it writes and in which conventions; `endopipe export` is the
command."""

from endopipe.export.case import ExportResult
from endopipe.export.formats import FORMATS, export_case

__all__ = ["FORMATS", "ExportResult", "export_case"]
