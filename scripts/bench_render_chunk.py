"""Time whole-image renders of a trained field (the held-out frames, as the NeRF stage renders
them) at several chunk sizes (`nerf.sampling.chunk`), alternated round by round so that the
machine's drift falls on every size alike, and check that the pixels are the same.

Run: `.venv/bin/python scripts/bench_render_chunk.py W/CASE --chunks 2048 4096 8192 --rounds 2
[--threads 2]`, alone on the machine. Prints the median seconds a frame per chunk size.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch

from endopipe.cli import build_pipeline
from endopipe.stages.nerf.render import render_image


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("case", type=Path)
    ap.add_argument("--chunks", type=int, nargs="+", default=[2048, 4096, 8192])
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--frames", type=int, default=4, help="held-out frames a round")
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    views = {s.name: s.View for s in build_pipeline().stages}
    ingest = views["ingest"](args.case / "01_ingest")
    poses = views["poses"](args.case / "02_poses")
    nerf = views["nerf"](args.case / "04_nerf")
    prior = views["centerline"](args.case / "03_centerline").prior()
    model = nerf.model()
    k = poses.intrinsics.scaled(ingest.width, ingest.height)
    c2w = nerf.c2w(poses)
    position = {f: p for p, f in enumerate(model.meta["frame_ids"])}
    frames = nerf.heldout[: args.frames]

    def render(i: int, chunk: int) -> dict[str, np.ndarray]:
        with torch.no_grad(), model.at_frame(position[i]):
            return render_image(model, prior, k, c2w[i], frame=position[i], chunk=chunk)

    seconds: dict[int, list[float]] = {c: [] for c in args.chunks}
    for _ in range(args.rounds):
        for chunk in args.chunks:
            for i in frames:
                t0 = time.perf_counter()
                render(i, chunk)
                seconds[chunk].append(time.perf_counter() - t0)
    first = {c: render(frames[0], c) for c in args.chunks}
    same = all(
        np.array_equal(first[c][key], first[args.chunks[0]][key])
        for c in args.chunks
        for key in first[c]
    )
    size = f"{ingest.width}x{ingest.height}"
    for chunk, s in seconds.items():
        print(f"chunk {chunk}: {np.median(s):.2f} s a {size} frame (median of {len(s)})")
    print("the same pixels at every size" if same else "the pixels differ between sizes")


if __name__ == "__main__":
    main()
