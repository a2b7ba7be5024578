"""RGB | our depth | ground-truth panel for a few frames of a finished case (the README picture).

    .venv/bin/python scripts/depth_figure.py WORKDIR/CASE OUT.png --frames 5 35 65 [--relief]
        [--beside WORKDIR/OTHER]

`--beside` puts the same frames' depth from other runs of the same input after the case's own
(two settings side by side).

Each depth is coloured as in 05_depth/preview.mp4, over its own 2-98th percentile range; pixels
with no depth are grey, outside the field of view black. The ground truth, when the case has one,
is read through the ingest view's door like every stage does.

`--relief` adds the surfaces (each run's, then the ground truth's) right of each frame's depths,
shaded as if lit from the camera: a colour map hides folds that change the depth by a few
percent, shading shows them. A relative ground truth (C3VD's panel) is first mapped onto our
depth by least squares, scale and shift (the score's fit, the other way round), since its
shading needs depth in one unit with ours.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from endopipe.stages.camera.rays import image_directions
from endopipe.stages.depth.evaluate import ground_truth_depths, inside_view
from endopipe.stages.depth.preview import colourise, has_depth
from endopipe.stages.depth.view import DepthView
from endopipe.stages.ingest.view import IngestView
from endopipe.stages.metrics.depth import affine_fit
from endopipe.stages.poses.view import PosesView

NO_DEPTH_GREY = 128
RELIEF_BLUR_PX = 1.5  # the panel is 8-bit: unblurred, its shading shows the quantisation's steps


def colour(depth: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """The preview's own colouring (stages.depth.preview) over this map's 2-98th percentiles,
    as BGR for cv2."""
    valid = inside & has_depth(depth)
    lo, hi = np.percentile(depth[valid], [2, 98]) if valid.any() else (0.0, 1.0)
    return cv2.cvtColor(colourise(depth, float(lo), float(hi), inside=inside), cv2.COLOR_RGB2BGR)


def relief(depth: np.ndarray, inside: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """The z-depth map's surface lit from the camera (|cos| of the normal to the view ray) as
    BGR; grey where there is no depth, black outside the field of view."""
    valid = inside & has_depth(depth)
    weight = cv2.GaussianBlur(valid.astype(np.float32), (0, 0), RELIEF_BLUR_PX)
    z = cv2.GaussianBlur(np.where(valid, depth, 0).astype(np.float32), (0, 0), RELIEF_BLUR_PX)
    z = z / np.maximum(weight, 1e-6)
    points = directions * z[..., None]
    normal = np.cross(np.gradient(points, axis=1), np.gradient(points, axis=0))
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True) + 1e-12
    view = directions / np.linalg.norm(directions, axis=-1, keepdims=True)
    shade = np.abs((normal * view).sum(-1))
    out = cv2.cvtColor((np.clip(shade, 0, 1) * 255).astype(np.uint8), cv2.COLOR_GRAY2BGR)
    out[inside & ~valid] = NO_DEPTH_GREY
    out[~inside] = 0
    return out


def in_our_unit(truth: np.ndarray, ours: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """A relative ground truth mapped onto our depth by least squares (0 stays no depth)."""
    both = inside & has_depth(truth) & has_depth(ours)
    scale, shift = affine_fit(truth[both].astype(float), ours[both].astype(float))
    return np.where(has_depth(truth), scale * truth + shift, 0.0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("case", type=Path)
    parser.add_argument("out", type=Path)
    parser.add_argument("--frames", type=int, nargs="+", default=[5, 35, 65])
    parser.add_argument("--relief", action="store_true", help="add both surfaces, shaded")
    parser.add_argument("--beside", type=Path, nargs="*", default=[], help="other runs' depth")
    args = parser.parse_args()
    ingest = IngestView(args.case / "01_ingest")
    depth = DepthView(args.case / "05_depth")
    inside = inside_view(ingest)
    source = ingest.ground_truth()
    truth = ground_truth_depths(source, ingest, args.frames)
    relative = source is not None and source.kind == "relative"
    camera = PosesView(args.case / "02_poses").intrinsics.scaled(ingest.width, ingest.height)
    directions = image_directions(camera)
    rows = []
    for i in args.frames:
        rgb = cv2.cvtColor(ingest.image(i), cv2.COLOR_RGB2BGR)
        rgb[~inside] = 0
        ours = depth.depth(i)
        others = [DepthView(other / "05_depth").depth(i) for other in args.beside]
        panels = [rgb, colour(ours, inside)] + [colour(o, inside) for o in others]
        if i in truth:
            panels.append(colour(truth[i], inside))
        if args.relief:
            panels += [relief(d, inside, directions) for d in [ours, *others]]
            if i in truth:
                panel = in_our_unit(truth[i], ours, inside) if relative else truth[i]
                panels.append(relief(panel, inside, directions))
        rows.append(np.concatenate(panels, 1))
    cv2.imwrite(str(args.out), np.concatenate(rows, 0))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
