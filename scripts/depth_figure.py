"""RGB | our depth | ground-truth panel for a few frames of a finished case (README picture).

    .venv/bin/python scripts/depth_figure.py WORKDIR/CASE OUT.png --frames 5 35 65

Each depth is coloured with its own 2-98th percentile range (turbo, near = blue); pixels with
no depth are grey, outside the field of view black. The ground truth, when the case has one,
is read through the ingest view's door like every stage does.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from endopipe.stages.depth.evaluate import ground_truth_depths
from endopipe.stages.depth.view import DepthView
from endopipe.stages.ingest.view import IngestView

GREY = (128, 128, 128)


def colour(depth: np.ndarray, inside: np.ndarray) -> np.ndarray:
    valid = inside & (depth > 0) & np.isfinite(depth)
    out = np.zeros((*depth.shape, 3), np.uint8)
    out[inside & ~valid] = GREY
    if valid.any():
        lo, hi = np.percentile(depth[valid], [2, 98])
        scaled = np.clip((depth - lo) / max(hi - lo, 1e-9), 0, 1)
        turbo = cv2.applyColorMap((scaled * 255).astype(np.uint8), cv2.COLORMAP_TURBO)
        out[valid] = turbo[valid]
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("case", type=Path)
    parser.add_argument("out", type=Path)
    parser.add_argument("--frames", type=int, nargs="+", default=[5, 35, 65])
    args = parser.parse_args()
    ingest = IngestView(args.case / "01_ingest")
    depth = DepthView(args.case / "05_depth")
    fov = ingest.fov()
    inside = fov > 0 if fov is not None else np.ones((ingest.height, ingest.width), bool)
    truth = ground_truth_depths(ingest.ground_truth(), ingest, args.frames)
    rows = []
    for i in args.frames:
        rgb = cv2.cvtColor(ingest.image(i), cv2.COLOR_RGB2BGR)
        rgb[~inside] = 0
        panels = [rgb, colour(depth.depth(i), inside)]
        if i in truth:
            panels.append(colour(truth[i], inside))
        rows.append(np.concatenate(panels, 1))
    cv2.imwrite(str(args.out), np.concatenate(rows, 0))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
