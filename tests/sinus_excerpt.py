"""A stretch of the real in-vivo sinus recording (../shared/data/jhu_sinus_381) as a case folder
of its own: its frames renumbered from 0, the scope's intrinsics and mask, and the authors' SfM
as gt/ (their poses and their points' depth: a reference, not the truth)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np


def write_excerpt(shared_data: Path, first: int, count: int, out: Path) -> Path:
    """Frames first..first+count-1 of the recording as the case folder `out`."""
    whole = out.with_name(out.name + "_whole")
    script = shared_data / "jhu_sinus_381" / "make_case.py"
    subprocess.run([sys.executable, str(script), str(whole)], check=True, capture_output=True)
    (out / "frames").mkdir(parents=True)
    (out / "gt" / "depth").mkdir(parents=True)
    for name in ("intrinsics.json", "mask.png"):
        shutil.copy(whole / name, out / name)
    poses = json.loads((whole / "gt" / "poses.json").read_text())
    for k in range(count):
        i = first + k
        shutil.copy(whole / "frames" / f"{i:06d}.jpg", out / "frames" / f"{k:06d}.jpg")
        depth = np.load(whole / "gt" / "depth" / f"{i:06d}.npy")
        np.save(out / "gt" / "depth" / f"{k:06d}.npy", depth)
    poses["poses"] = poses["poses"][first : first + count]
    (out / "gt" / "poses.json").write_text(json.dumps(poses))
    shutil.rmtree(whole)
    return out
