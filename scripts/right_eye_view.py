"""A new view, not a new time: a finished stereo case's field, trained on the left eye only,
rendered from the right eye and scored against the right eye's frames, beside its held-out PSNR
(left frames at times it did not train on).

Run: `.venv/bin/python scripts/right_eye_view.py WORKDIR/CASE [--frames 8]` on a case run
through the nerf stage from an input with rectified right views (a Hamlyn sequence, `endopipe
synth ... --layout hamlyn --stereo`). The right camera is the left one moved by the rig's
baseline along its +x (docs/formats.md: a rectified rig), in the poses' units (millimetres:
stereo poses are metric). Prints the right eye's PSNR on `--frames` frames (training and
held-out times alike, spread over the clip), over the right eye's image and over the pixels whose
surface the left eye saw too (the band the baseline uncovers no left frame showed), beside the
stage's held-out PSNR; an instrument the detector finds in the right eye is left out, as ingest
leaves the left eye's out. The scope's light stays at the left eye (the rig carries one light).
A benchmark.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from endopipe.stages.camera import image_directions, lens_valid_mask, project_camera
from endopipe.stages.centerline.view import CenterlineView
from endopipe.stages.ingest.config import IngestConfig
from endopipe.stages.ingest.masks import specular_mask
from endopipe.stages.ingest.rig_check import RigCheck, mended_right
from endopipe.stages.ingest.selection import resize
from endopipe.stages.ingest.tool_detect import detect_tools
from endopipe.stages.ingest.view import IngestView
from endopipe.stages.io.sources import open_input
from endopipe.stages.nerf import losses
from endopipe.stages.nerf.render import render_image
from endopipe.stages.nerf.view import NerfView
from endopipe.stages.poses.view import PosesView

#: The highlight and instrument detectors as ingest runs them by default.
SPECULAR = IngestConfig().specular
TOOLS = IngestConfig().tools


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("case", type=Path)
    ap.add_argument("--frames", type=int, default=8)
    args = ap.parse_args()
    ingest = IngestView(args.case / "01_ingest")
    poses = PosesView(args.case / "02_poses")
    nerf = NerfView(args.case / "04_nerf")
    prior = CenterlineView(args.case / "03_centerline").prior()
    source = open_input(Path(ingest.file.source.path), format=ingest.file.source.kind)
    if source.stereo is None:
        raise SystemExit(f"{args.case}: its input has no right views")
    if not poses.metric:
        raise SystemExit(f"{args.case}: its poses are not metric (the baseline has no scale)")
    model = nerf.model()
    k = poses.intrinsics.scaled(ingest.width, ingest.height)
    c2w = nerf.c2w(poses)
    position = {f: p for p, f in enumerate(model.meta["frame_ids"])}
    lens = lens_valid_mask(k)
    fov = ingest.fov()
    if fov is None:
        fov = lens.astype(np.uint8) * 255
    ids = [i for i in poses.registered if i in position]
    picked = [ids[int(round(x))] for x in np.linspace(0, len(ids) - 1, min(args.frames, len(ids)))]
    shift = np.eye(4)
    shift[0, 3] = source.stereo.baseline_mm  # the right eye: the left one moved along its +x
    rig = ingest.file.stereo.rig if ingest.file.stereo else None
    offset = rig.frame_offset if rig else 0  # the right frame of the same moment
    scores, shared = [], []
    for i in picked:
        right = source.stereo.right(ingest.frame(i).source_index + offset)
        if right is None:
            continue
        right_u8 = resize(right, (ingest.width, ingest.height))
        right = right_u8
        right = mended_right(right, rig or RigCheck(), k).astype(np.float32) / 255.0
        with model.at_frame(position[i]):
            # the right eye moved, the scope's light did not: it stays at the left eye
            out = render_image(model, prior, k, c2w[i] @ shift, frame=position[i], light_c2w=c2w[i])
        rgb = out["rgb"]
        # not the right eye's black rectification band, its highlights (view-dependent) nor an
        # instrument in it: the left frames' are left out of training and scoring as well
        usable = lens & (right.max(-1) > 0.02) & (specular_mask(right_u8, SPECULAR) == 0)
        if ingest.tool_mask(i) is not None:  # ingest found or was given the left eye's
            usable &= ~detect_tools(right_u8, fov, TOOLS)
        both = usable & seen_by_left(k, out["depth"], shift, lens)
        err = ((rgb - right) ** 2).mean(-1)
        scores.append(losses.psnr(float(err[usable].mean())))
        shared.append(losses.psnr(float(err[both].mean())))
        print(
            f"frame {i}: right eye {scores[-1]:.2f} dB; where the left eye saw the surface too "
            f"({both.sum() / max(usable.sum(), 1):.0%} of it) {shared[-1]:.2f} dB",
            flush=True,
        )
    held = nerf.metrics.psnr if nerf.metrics else None
    print(
        f"right eye, rendered from the left eye's field: {np.mean(scores):.2f} dB over "
        f"{len(scores)} frames ({np.mean(shared):.2f} dB where the left eye saw it too); "
        f"held-out left frames: {held:.2f} dB"
    )


def seen_by_left(k, depth: np.ndarray, shift: np.ndarray, lens: np.ndarray) -> np.ndarray:
    """The right eye's pixels whose rendered surface the left eye sees inside its lens: the
    rest (a band as wide as the disparity) no left frame showed, and no field can know."""
    dirs = image_directions(k)
    points = dirs * depth[..., None] + shift[:3, 3]  # right camera -> left camera frame
    uv, z = project_camera(k, points.reshape(-1, 3))
    u, v = np.round(uv[:, 0]).astype(int), np.round(uv[:, 1]).astype(int)
    inside = (z > 0) & (u >= 0) & (u < k.width) & (v >= 0) & (v < k.height)
    seen = np.zeros(len(u), bool)
    seen[inside] = lens[v[inside], u[inside]]
    return seen.reshape(depth.shape) & (depth > 0)


if __name__ == "__main__":
    main()
