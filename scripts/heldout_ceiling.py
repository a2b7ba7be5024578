"""How far above the neighbour average a held-out frame can be predicted, for a finished case:
what the held-out PSNR the depth stage reports should be read against.

    .venv/bin/python scripts/heldout_ceiling.py WORKDIR/CASE [--ranks 8 16 32 64]

On the held-out frames (every `nerf.train.holdout_every`-th, as the NeRF stage holds out), on
the pixels its PSNR counts (the ingest masks), it prints:

- **neighbour average**: the frames before and after averaged (the report's baseline);
- **flow interpolation**: the same two frames each moved half-way along the optical flow to
  the other (OpenCV's DIS flow, both directions) and averaged: a predictor that follows the
  tissue's motion, as a field that deforms would, and knows no geometry;
- **rank-k video**: the training frames' best rank-k approximation (SVD of the frames as
  vectors, their mean removed) with each held-out frame's k coefficients the average of its
  neighbours': the ceiling of a field whose change over time is k modes shared by all pixels
  (a HexPlane plane over (x, y) times a change over (z, t), seen head-on), beside that
  approximation's fit on the training frames.

A still camera's held-out frame is a new time, not a new view: these say how much of the
neighbour average any model, 3D or not, can beat on that footage.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from endopipe.stages.ingest.view import IngestView
from endopipe.stages.metrics.baselines import neighbour_average, neighbour_frames
from endopipe.stages.metrics.depth import image_metrics
from endopipe.stages.nerf.view import NerfView


def moved_half_way(image: np.ndarray, towards: np.ndarray) -> np.ndarray:
    """`image` moved half-way along the DIS flow that takes `towards` onto it (backward warping:
    each output pixel reads `image` half a flow step away)."""
    grey = [cv2.cvtColor((x * 255).astype(np.uint8), cv2.COLOR_RGB2GRAY) for x in (towards, image)]
    flow = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM).calc(*grey, None)
    h, w = flow.shape[:2]
    gx, gy = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    return cv2.remap(
        image,
        gx + 0.5 * flow[..., 0],
        gy + 0.5 * flow[..., 1],
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REPLICATE,
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("case", type=Path, help="a finished case folder (its 01_ingest and 04_nerf)")
    ap.add_argument("--ranks", type=int, nargs="+", default=[8, 16, 32, 64])
    args = ap.parse_args()

    ingest = IngestView(args.case / "01_ingest")
    held = NerfView(args.case / "04_nerf").heldout
    order = [f.index for f in ingest.frames]
    held_set = set(held)
    train = [i for i in order if i not in held_set]
    image = {i: ingest.image(i).astype(np.float32) / 255.0 for i in order}
    mask = {i: ingest.mask(i) > 127 for i in order}  # the pixels the PSNR counts
    scored = []
    rows: dict[str, list[float]] = {"neighbour average": [], "flow interpolation": []}
    for i in held:
        near = neighbour_frames(i, order, held_set)
        if len(near) < 2:
            continue  # an end frame: one neighbour, nothing to interpolate
        scored.append((i, near))
        a, b = (image[j] for j in near)
        rows["neighbour average"].append(
            image_metrics(neighbour_average([a, b]), image[i], mask[i])["psnr"]
        )
        flowed = 0.5 * (moved_half_way(a, b) + moved_half_way(b, a))
        rows["flow interpolation"].append(image_metrics(flowed, image[i], mask[i])["psnr"])

    frames = np.stack([image[i].reshape(-1) for i in train], 1)
    mean = frames.mean(1, keepdims=True)
    u, s, vt = np.linalg.svd(frames - mean, full_matrices=False)
    fit_rows: dict[str, list[float]] = {}
    for k in args.ranks:
        coef = vt[:k] * s[:k, None]  # (k, training frames)
        rows[f"rank-{k} video"] = [
            image_metrics(
                (mean[:, 0] + u[:, :k] @ coef[:, [train.index(j) for j in near]].mean(1)).reshape(
                    image[i].shape
                ),
                image[i],
                mask[i],
            )["psnr"]
            for i, near in scored
        ]
        fit_rows[f"rank-{k} video"] = [
            image_metrics(
                (mean[:, 0] + u[:, :k] @ coef[:, n]).reshape(image[j].shape),
                image[j],
                mask[j],
            )["psnr"]
            for n, j in enumerate(train)
        ]
    print(f"{len(scored)} held-out frames with two neighbours, PSNR (dB) on the ingest masks")
    for name, values in rows.items():
        fit = fit_rows.get(name)
        extra = f"   (training frames fitted: {np.mean(fit):.2f})" if fit else ""
        print(f"  {name:20s} {np.mean(values):6.2f}{extra}")


if __name__ == "__main__":
    main()
