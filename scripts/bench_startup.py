"""Start-up time of the commands a user types most: `endopipe --help` and `endopipe status CASE`.

Run: `.venv/bin/python scripts/bench_startup.py [--runs 15]`. It makes a small image-folder case
and runs its ingest once (not timed), then times each command as a fresh process and prints the
median and the spread. A benchmark, not a test: the machine's load moves these numbers.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

ENDOPIPE = [sys.executable, "-m", "endopipe"]


def make_case(root: Path) -> tuple[Path, str]:
    """An 8-frame image folder run up to ingest: (workdir, case name)."""
    frames = root / "frames"
    frames.mkdir()
    rng = np.random.default_rng(0)
    base = cv2.resize(rng.random((32, 64, 3)).astype(np.float32), (200, 128)) * 200 + 30
    for i in range(8):
        cv2.imwrite(str(frames / f"{i:04d}.png"), base[:, 4 * i : 4 * i + 160].astype(np.uint8))
    cmd = [*ENDOPIPE, "run", str(frames), "--workdir", str(root / "wd"), "--until", "ingest"]
    subprocess.run([*cmd, "--name", "startup", "--quiet"], check=True, capture_output=True)
    return root / "wd", "startup"


def time_command(args: list[str], runs: int) -> list[float]:
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        subprocess.run(args, check=True, capture_output=True)
        times.append(time.perf_counter() - t0)
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=15)
    runs = parser.parse_args().runs
    with tempfile.TemporaryDirectory() as tmp:
        wd, case = make_case(Path(tmp))
        commands = {
            "endopipe --help": [*ENDOPIPE, "--help"],
            "endopipe status CASE": [*ENDOPIPE, "status", case, "--workdir", str(wd)],
        }
        for name, args in commands.items():
            t = time_command(args, runs)
            print(
                f"{name:24s} median {statistics.median(t):.3f} s  "
                f"min {min(t):.3f} s  max {max(t):.3f} s  ({runs} runs)"
            )


if __name__ == "__main__":
    main()
