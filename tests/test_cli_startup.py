"""`endopipe --help` and `endopipe status` start fast: they import no torch, OpenCV, pycolmap
or numpy (the timing itself is measured with hyperfine, not in a test)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from endopipe.cli import all_stages, planning_pipeline

HEAVY = ("torch", "cv2", "pycolmap", "numpy", "scipy", "open3d", "trimesh", "matplotlib", "av")

PROBE = """
import json, sys
from endopipe.cli import main
code = main({args!r})
heavy = sorted(m for m in {heavy!r} if m in sys.modules)
print(json.dumps({{"code": code, "heavy": heavy}}))
"""


def _imports_of(*args: str) -> dict:
    code = PROBE.format(args=list(args), heavy=HEAVY)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_help_imports_no_heavy_library() -> None:
    assert _imports_of("--help") == {"code": 0, "heavy": []}


def test_status_imports_no_heavy_library(tmp_path: Path) -> None:
    case = tmp_path / "wd" / "c"
    case.mkdir(parents=True)
    info = {"name": "c", "input": str(tmp_path / "c.mp4"), "kind": "video", "input_digest": "0"}
    (case / "case.json").write_text(json.dumps(info))
    assert _imports_of("status", "c", "--workdir", str(tmp_path / "wd")) == {
        "code": 0,
        "heavy": [],
    }


def test_planning_pipeline_reads_what_the_stage_classes_say() -> None:
    """status plans with the stages read from source; they must agree with the imported ones."""
    read = planning_pipeline().stages
    for declared, cls in zip(read, all_stages(), strict=True):
        assert (declared.name, declared.needs, declared.version) == (
            cls.name,
            tuple(cls.needs),
            cls.version,
        )
        assert (declared.resumable, declared.Config, declared.describe()) == (
            cls.resumable,
            cls.Config,
            cls.describe(),
        )
        assert (declared.Summary, declared.View) == (cls.Summary, cls.View)
        assert declared.load() is cls


VIEW_PROBE = """
import json, sys
from endopipe.cli import planning_pipeline
stages = planning_pipeline().by_name
views = {name: stages[name].View.__name__ for name in ("poses", "nerf", "depth")}
print(json.dumps({"views": views, "stage_modules": sorted(
    m for m in sys.modules if m.startswith("endopipe.stages.") and m.endswith(".stage")
), "torch": "torch" in sys.modules}))
"""


def test_a_declared_stage_gives_its_view_without_importing_the_stage() -> None:
    """Commands that only read folders (status, bench, batch) open views, not stage modules:
    the NeRF's would import torch and the training code."""
    proc = subprocess.run(
        [sys.executable, "-c", VIEW_PROBE], capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    got = json.loads(proc.stdout.strip().splitlines()[-1])
    assert got["views"] == {"poses": "PosesView", "nerf": "NerfView", "depth": "DepthView"}
    assert got == {"views": got["views"], "stage_modules": [], "torch": False}
