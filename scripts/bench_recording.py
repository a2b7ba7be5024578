"""A synthetic colonoscope withdrawal end to end through the recording path: one table row.

Run: `.venv/bin/python scripts/bench_recording.py --frames 400 --workdir W [--seed 7]
[-- extra endopipe run options]`. Writes (once) the withdrawal `W/inputs/withdrawal_<frames>`
with `endopipe synth` (0.3 mm a frame at 25 fps, a pause every ~130 frames, 3% blurred and 2%
washed-out frames), runs `endopipe run` on it in a child process, and prints the wall time, the
largest peak memory of the run's processes, the disk it left per minute of video, and the
recording's scores (its summary, read through the recording's view). A benchmark, not a test.
"""

from __future__ import annotations

import argparse
import resource
import subprocess
import sys
import time
from pathlib import Path

from endopipe.recording.view import RecordingView


def synth(out: Path, frames: int, seed: int) -> None:
    if (out / "gt" / "synth.json").is_file():
        return
    pauses = max(1, frames // 130)
    cmd = [sys.executable, "-m", "endopipe", "synth", str(out), "--seed", str(seed)]
    cmd += ["--frames", str(frames), "--step-mm", "0.3", "--pauses", str(pauses)]
    cmd += ["--blurred", "0.03", "--washed-out", "0.02", "--fps", "25"]
    subprocess.run(cmd, check=True)


def disk_mb(folder: Path) -> float:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file()) / 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=400)
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--workdir", type=Path, required=True)
    parser.add_argument("extra", nargs="*", help="more `endopipe run` options, after --")
    args = parser.parse_args()
    name = f"withdrawal_{args.frames}"
    src = args.workdir / "inputs" / name
    synth(src, args.frames, args.seed)
    cmd = [sys.executable, "-m", "endopipe", "run", str(src), "--workdir", str(args.workdir)]
    t0 = time.perf_counter()
    subprocess.run([*cmd, *args.extra], check=True)
    wall = time.perf_counter() - t0
    peak_mb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    case = args.workdir / name
    s = RecordingView(case).summary
    minutes = args.frames / 25 / 60
    cells = {
        "frames": args.frames,
        "keyframes": s.keyframes,
        "windows": len(s.windows),
        "wall": f"{wall / 60:.1f} min",
        "peak RSS": f"{peak_mb / 1024:.2f} GiB",
        "disk per minute of video": f"{disk_mb(case) / minutes / 1000:.2f} GB",
        "ATE % path": s.ate_percent_of_path,
        "frames posed": f"{s.frames_posed} / {s.frames}",
        "depth AbsRel all / keyframes": (
            f"{s.depth_abs_rel_all_frames:.4f} / {s.depth_abs_rel_keyframes:.4f}"
            if s.depth_abs_rel_all_frames is not None
            else "-"
        ),
        "Chamfer % radius": s.chamfer_pct_radius,
        "off seen %": s.off_seen_pct,
        "verdict": s.verdict,
    }
    print("| " + " | ".join(cells) + " |")
    print("|" + "---|" * len(cells))
    print(
        "| "
        + " | ".join(f"{v:.3g}" if isinstance(v, float) else str(v) for v in cells.values())
        + " |"
    )


if __name__ == "__main__":
    main()
