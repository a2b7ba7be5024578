"""A recording forced through small windows against the same input in one window (a short
clip's path): how far the joined trajectory is from the single-window one, and both depth
scores.

Run, on cases that `endopipe run` made of the same input:
`.venv/bin/python scripts/compare_windowed.py WORKDIR/windowed WORKDIR/single`, e.g. after
`endopipe run ../shared/data/c3vd_v3_preview --name windowed --window 30 --overlap 10 --set
ingest.keyframes.mode=content --set ingest.keyframes.min_flow=0.0001` (every frame a keyframe)
and `endopipe run ../shared/data/c3vd_v3_preview --name single`. The trajectories are compared
after a similarity (the single window's path length is the unit of the percentage). A
benchmark, not a test.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from endopipe.cli import build_pipeline
from endopipe.recording.cameras import cameras_by_source
from endopipe.recording.view import RecordingView
from endopipe.stages.metrics.depth import pose_metrics


def joined_trajectory(case: Path) -> dict[int, np.ndarray]:
    frames = RecordingView(case).trajectory().frames
    return {f.source_index: np.array(f.c2w) for f in frames if f.segment == 0}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("windowed", type=Path)
    parser.add_argument("single", type=Path)
    args = parser.parse_args()
    pipe = build_pipeline()
    joined, single = joined_trajectory(args.windowed), cameras_by_source(pipe, args.single)
    m = pose_metrics(joined, single)
    summary = RecordingView(args.windowed).summary
    print(
        f"{len(summary.windows)} windows, {summary.segments} segment(s), verdict "
        f"{summary.verdict}; joined vs single window over {int(m['frames'])} frames: "
        f"{m['ate_percent_of_path']:.2f}% of the path, rotation {m['rre_deg']:.2f} deg"
    )
    if summary.depth_abs_rel_all_frames is None:
        return
    relative = summary.depth_gt_kind == "relative"
    depth = pipe.view(args.single, "depth").summary
    block = depth.affine_invariant if relative else depth.median_scaled
    name = "Spearman / SSI-AbsRel / coverage" if relative else "AbsRel / coverage"
    ours = [summary.depth_abs_rel_all_frames, summary.depth_coverage_all_frames]
    one = [block.abs_rel, block.coverage]
    if relative:
        ours.insert(0, summary.depth_spearman_all_frames)
        one.insert(0, block.spearman)
    print(
        f"depth {name}: windowed {' / '.join(f'{v:.4f}' for v in ours)} over "
        f"{summary.depth_frames_scored} frames; single window "
        f"{' / '.join(f'{v:.4f}' for v in one)}"
    )


if __name__ == "__main__":
    main()
