"""RGB | our depth | ground-truth panel for a few frames of a finished case (README picture).

    .venv/bin/python scripts/depth_figure.py WORKDIR/CASE OUT.png --frames 5 35 65

Each depth is coloured as in 05_depth/preview.mp4, over its own 2-98th percentile range; pixels
with no depth are grey, outside the field of view black. The ground truth, when the case has one,
is read through the ingest view's door like every stage does.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from endopipe.stages.depth.evaluate import ground_truth_depths
from endopipe.stages.depth.preview import colourise, has_depth
from endopipe.stages.depth.view import DepthView
from endopipe.stages.ingest.view import IngestView


def colour(depth: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """The preview's own colouring (stages.depth.preview) over this map's 2-98th percentiles,
    as BGR for cv2."""
    valid = inside & has_depth(depth)
    lo, hi = np.percentile(depth[valid], [2, 98]) if valid.any() else (0.0, 1.0)
    return cv2.cvtColor(colourise(depth, float(lo), float(hi), inside=inside), cv2.COLOR_RGB2BGR)


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
