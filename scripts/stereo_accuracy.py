"""The stereo matcher's depth against exact truth on synthetic stereo Hamlyn sequences.

    .venv/bin/python scripts/stereo_accuracy.py [--seeds 0 1 2] [--frames 6] [--size 320x256]
        [--set block_size=5 ...]

Each seed's sequence is written as `endopipe synth --layout hamlyn --stereo` writes it, read
back through the Hamlyn reader (its StereoPairs), matched at its own size, and scored on every
pixel with truth: AbsRel on the pixels the matcher gave a depth, and that share (coverage).
"""

from __future__ import annotations

import argparse
import tempfile
from functools import partial
from pathlib import Path

import numpy as np

import endopipe.stages  # noqa: F401  (cv2 first)
from endopipe.stages.ingest.config import StereoConfig
from endopipe.stages.ingest.stereo import match_depth
from endopipe.stages.io.sources import open_input
from endopipe.synth import Layout, SynthConfig, generate_case
from endopipe.synth.hamlyn_sink import HamlynSink

BASELINE_MM = 5.0


def score(seq: Path, cfg: StereoConfig) -> list[tuple[float, float]]:
    """(AbsRel, coverage) of every frame."""
    source = open_input(seq)
    assert source.stereo is not None and source.intrinsics is not None
    truth = source.ground_truth()
    out = []
    for frame in source.frames():
        right = source.stereo.right(frame.source_index)
        depth = match_depth(frame.rgb, right, source.intrinsics.fx, source.stereo.baseline_mm, cfg)
        gt = truth.depth(frame.source_index)
        valid = gt > 0
        got = valid & (depth > 0)
        rel = np.abs(depth[got] - gt[got]) / gt[got]
        out.append((float(rel.mean()), float(got.sum() / valid.sum())))
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--frames", type=int, default=6)
    ap.add_argument("--size", default="320x256")
    ap.add_argument("--shape", default="colon")
    ap.add_argument("--set", nargs="*", default=[], help="StereoConfig fields, key=value")
    args = ap.parse_args()
    w, h = (int(v) for v in args.size.split("x"))
    cfg = StereoConfig(**dict(kv.split("=", 1) for kv in args.set))
    layout = Layout("hamlyn", partial(HamlynSink, baseline_mm=BASELINE_MM), takes_right=True)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in args.seeds:
            seq = Path(tmp) / f"rectified{seed:02d}"
            synth = SynthConfig(
                seed=seed,
                frames=args.frames,
                width=w,
                height=h,
                shape=args.shape,
                stereo_baseline_mm=BASELINE_MM,
            )
            generate_case(seq, synth, layout=layout)
            frames = score(seq, cfg)
            abs_rel, cover = (float(np.mean(v)) for v in zip(*frames, strict=True))
            worst = max(a for a, _ in frames)
            rows.append((abs_rel, cover))
            print(
                f"seed {seed}: AbsRel {abs_rel:.4f} (worst frame {worst:.4f}), coverage {cover:.3f}"
            )
    a, c = np.array(rows).T
    print(
        f"mean over {len(rows)} seeds: AbsRel {a.mean():.4f} +- {a.std():.4f}, coverage "
        f"{c.mean():.3f} +- {c.std():.3f}"
    )


if __name__ == "__main__":
    main()
