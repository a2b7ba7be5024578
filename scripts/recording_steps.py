"""Where a recording's error enters, step by step, against its truth (or a reference SfM given as
its truth): the keyframes, the SfM that posed them (the one SfM, or each window's own), the
segments as joined, every frame registered, and the depth of each window, of every frame, and
at one scale a segment.

Run: `.venv/bin/python scripts/recording_steps.py WORKDIR/CASE` on a recording that
`endopipe run` finished. Prints one markdown table. A diagnosis, not a test.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from endopipe.cli import build_pipeline
from endopipe.recording.cameras import cameras_by_source, truth_poses
from endopipe.recording.view import RecordingView
from endopipe.stages.metrics.depth import pose_metrics


def ate(est: dict[int, np.ndarray], truth: list[np.ndarray]) -> str:
    """ATE, % of the path, after one similarity (and the frames it is over)."""
    est = {i: c for i, c in est.items() if i < len(truth)}
    if len(est) < 3:
        return "-"
    m = pose_metrics(est, {i: truth[i] for i in est})
    return f"{m['ate_percent_of_path']:.2f}% ({len(est)})"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("case", type=Path)
    args = parser.parse_args()
    pipe = build_pipeline()
    view = RecordingView(args.case)
    s = view.summary
    truth = truth_poses(pipe.view(args.case, "ingest"))
    if truth is None:
        raise SystemExit(f"{args.case}: no ground-truth poses to score against")
    joined = view.trajectory()
    frames = view.frames() if (view.folder / "frames.json").is_file() else []
    rows: list[tuple[str, str]] = [
        ("keyframes (of the frames ingest judged)", f"{s.keyframes} ({s.frames})")
    ]
    if s.one_sfm:
        rows.append(
            ("the one SfM, every keyframe it posed", ate(cameras_by_source(pipe, args.case), truth))
        )
    for w in s.windows:
        if w.status == "ok":
            own = cameras_by_source(pipe, view.windows_dir / w.name)
            rows.append((f"{w.name}'s poses alone", ate(own, truth)))
    for k in range(joined.segments):
        keys = {f.source_index: np.array(f.c2w) for f in joined.frames if f.segment == k}
        rows.append((f"segment {k} as joined, keyframes", ate(keys, truth)))
        every = {f.source_index: np.array(f.c2w) for f in frames if f.segment == k and f.c2w}
        rows.append((f"segment {k}, every posed frame", ate(every, truth)))
    junctions = "; ".join(
        f"{j.a}-{j.b}: " + (f"{j.error_pct:.2f}%" if j.joined else j.reason)
        for j in joined.junctions
    )
    rows.append(("junctions", junctions or "-"))
    posed = f"{s.frames_posed} of {s.frames}" if s.frames else "-"
    rows.append(("frames posed and given depth", posed))
    for w in s.windows:
        if w.depth_abs_rel is not None:
            rows.append((f"{w.name}'s depth AbsRel, its keyframes", f"{w.depth_abs_rel:.4f}"))
    for label, value in (
        ("depth AbsRel, every posed frame", s.depth_abs_rel_all_frames),
        ("depth AbsRel, keyframes", s.depth_abs_rel_keyframes),
        ("depth AbsRel, one scale a segment", s.depth_abs_rel_one_scale),
        ("the brightness guess's AbsRel, same pixels", s.brightness_guess_abs_rel),
    ):
        rows.append((label, "-" if value is None else f"{value:.4f}"))
    print("| step | error |\n| --- | --- |")
    for label, value in rows:
        print(f"| {label} | {value} |")


if __name__ == "__main__":
    main()
