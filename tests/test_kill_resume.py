"""A stage killed with SIGKILL leaves no partial stage folder; the next run completes."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from tests.conftest import textured_frames, write_video


def test_sigkill_mid_ingest_leaves_no_partial_folder(tmp_path: Path) -> None:
    video = write_video(tmp_path / "long.mp4", textured_frames(240, 320, 256))
    wd = tmp_path / "wd"
    cmd = [sys.executable, "-m", "endopipe", "run", str(video), "--workdir", str(wd)]
    cmd += ["--until", "ingest", "--quiet", "--set", "ingest.drop_duplicates=false"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    case = wd / "long"
    deadline = time.time() + 120
    while time.time() < deadline:  # wait until ingest is writing frames into its temp folder
        temps = list(case.glob(".01_ingest.tmp-*/frames/*.png"))
        if len(temps) >= 5:
            break
        assert proc.poll() is None, (
            "ingest finished before it could be killed; make the input longer"
        )
        time.sleep(0.02)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert not (case / "01_ingest").exists()
    assert list(case.glob(".01_ingest.tmp-*")), "the kill should have left only a temp folder"
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert (case / "01_ingest" / "manifest.json").is_file()
    assert len(list((case / "01_ingest" / "frames").glob("*.png"))) == 240
    assert not list(case.glob(".01_ingest.tmp-*")), "stale temp folders are cleaned"
