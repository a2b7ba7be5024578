"""pycolmap imported before cv2 makes cv2.imwrite of a PNG abort, and its import takes SIGTERM
over; our entry points prevent both.

`endopipe.stages` makes any later `import pycolmap` import cv2 first (without importing cv2
itself, so `endopipe --help` stays fast) and puts SIGTERM's handler back."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

SCRIPT = """
import endopipe.stages  # the one place every entry point passes through
import pycolmap          # noqa: F401
import cv2, numpy as np
ok = cv2.imwrite(r"{out}", np.full((8, 8, 3), 127, np.uint8))
print("written" if ok else "failed")
"""

CLI_THEN_COLMAP = """
import sys
import endopipe.cli
assert "cv2" not in sys.modules, "the CLI module alone should not load OpenCV"
from endopipe.stages.io import colmap_model  # a stage library that imports pycolmap lazily
import pycolmap
order = list(sys.modules)
print(order.index("cv2") < order.index("pycolmap"))
"""


def _python(code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)


def test_png_write_survives_pycolmap_import(tmp_path: Path) -> None:
    out = tmp_path / "probe.png"
    proc = _python(SCRIPT.format(out=out))
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "written" in proc.stdout and out.stat().st_size > 0


def test_pycolmap_imported_through_the_cli_comes_after_cv2() -> None:
    proc = _python(CLI_THEN_COLMAP)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.strip() == "True"


SIGTERM_AFTER_COLMAP = """
import os, signal, time
import endopipe.stages
import pycolmap  # installs glog's failure handler for SIGTERM, among others
os.kill(os.getpid(), signal.SIGTERM)
time.sleep(5)
"""


def test_pycolmap_leaves_sigterm_as_it_was() -> None:
    """glog's handler would print a native stack trace on SIGTERM; the default stays: the
    process ends by the signal, silently."""
    proc = _python(SIGTERM_AFTER_COLMAP)
    assert proc.returncode == -15, proc.stderr[-2000:]
    assert "stack trace" not in proc.stderr and "SIGTERM" not in proc.stderr
