"""`endopipe export`: a processed case in other tools' formats (nerfstudio, colmap, endonerf,
ply), one module per format over the shared case loading of case.py; command.py is the entry
point `export_case`. Each format's module says what it writes and in which conventions."""

from endopipe.commands.export.case import ExportResult
from endopipe.commands.export.command import FORMATS, export_case

__all__ = ["FORMATS", "ExportResult", "export_case"]
