"""Where a recording's whole-path error comes from: each window's scale against the truth after
one similarity for the whole joined path, the scale drift inside each window, and (--meshes)
each window's keyframes fused alone and scored as the recording's one mesh is.

Run: `.venv/bin/python scripts/recording_drift.py WORKDIR/CASE [--meshes]` on a recording that
`endopipe run` finished (a synthetic one: it needs the truth's poses). A diagnosis, not a test.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from endopipe.cli import build_pipeline
from endopipe.pipeline.config import load_config
from endopipe.recording.cameras import truth_poses
from endopipe.recording.fuse import one_mesh
from endopipe.recording.summary import RecordingSummary
from endopipe.recording.view import RecordingView
from endopipe.stages.camera.transforms import umeyama


def centres(frames: list, truth: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    est = np.array([np.array(f.c2w)[:3, 3] for f in frames])
    return est, np.array([truth[f.source_index][:3, 3] for f in frames])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("case", type=Path)
    parser.add_argument("--meshes", action="store_true", help="fuse each window alone too")
    args = parser.parse_args()
    pipe = build_pipeline()
    view = RecordingView(args.case)
    joined = view.trajectory()
    ingest = pipe.view(args.case, "ingest")
    truth = truth_poses(ingest)
    if truth is None:
        raise SystemExit(f"{args.case}: no ground-truth poses to measure drift against")
    configs = load_config(pipe.stages, [str(args.case / "config.yaml")], [])
    seg = [f for f in joined.frames if f.segment == 0]
    s_all, _, _ = umeyama(*centres(seg, truth))
    print(
        "| window | keyframes | drawn size vs the whole path | drawn size, last / first third "
        "| own mesh Chamfer % r |"
    )
    print("|---|---|---|---|---|")
    for name in sorted({f.window for f in seg}):
        own = [f for f in seg if f.window == name]
        s, _, _ = umeyama(*centres(own, truth))
        k = len(own) // 3
        first, _, _ = umeyama(*centres(own[:k], truth))
        last, _, _ = umeyama(*centres(own[-k:], truth))
        chamfer = "-"
        if args.meshes:
            part = joined.model_copy(update={"frames": own})
            summary = RecordingSummary(
                keyframes=0, windows=[], segments=1, posed_keyframes=0, verdict="ok"
            )
            one_mesh(pipe, view.windows_dir, part, configs, ingest, truth, summary)
            chamfer = f"{summary.chamfer_pct_radius:.2f}"
        # umeyama's scale maps the estimate onto the truth: a window drawn larger has a smaller one
        print(f"| {name} | {len(own)} | {s_all / s:.4f} | {first / last:.4f} | {chamfer} |")


if __name__ == "__main__":
    main()
