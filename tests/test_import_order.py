"""pycolmap imported before cv2 makes cv2.imwrite of a PNG abort; our entry points prevent it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

SCRIPT = """
import endopipe.stages  # the one place every entry point passes through: imports cv2 first
import pycolmap          # noqa: F401
import cv2, numpy as np
ok = cv2.imwrite(r"{out}", np.full((8, 8, 3), 127, np.uint8))
print("written" if ok else "failed")
"""


def test_png_write_survives_pycolmap_import(tmp_path: Path) -> None:
    out = tmp_path / "probe.png"
    proc = subprocess.run(
        [sys.executable, "-c", SCRIPT.format(out=out)], capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "written" in proc.stdout and out.stat().st_size > 0


def test_cli_module_imports_cv2_before_pycolmap() -> None:
    proc = subprocess.run(
        [sys.executable, "-c", "import endopipe.cli, sys; print(list(sys.modules).index('cv2'))"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
