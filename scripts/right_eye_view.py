"""A new view, not a new time: a finished stereo case's field, trained on the left eye only,
rendered from the right eye and scored against the right eye's frames, beside its held-out PSNR
(left frames at times it did not train on).

Run: `.venv/bin/python scripts/right_eye_view.py WORKDIR/CASE [--frames 8]` on a case run
through the nerf stage from an input with rectified right views (a Hamlyn sequence, `endopipe
synth ... --layout hamlyn --stereo`). The right camera is the left one moved by the rig's
baseline along its +x (docs/formats.md: a rectified rig), in the poses' units (millimetres:
stereo poses are metric). Prints the right eye's PSNR on `--frames` frames (training and
held-out times alike, spread over the clip) and the stage's held-out PSNR. A benchmark.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from endopipe.stages.camera import lens_valid_mask
from endopipe.stages.centerline.view import CenterlineView
from endopipe.stages.ingest.rig_check import RigCheck, mended_right
from endopipe.stages.ingest.selection import resize
from endopipe.stages.ingest.view import IngestView
from endopipe.stages.io.sources import open_input
from endopipe.stages.nerf import losses
from endopipe.stages.nerf.render import render_image
from endopipe.stages.nerf.view import NerfView
from endopipe.stages.poses.view import PosesView


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
    ids = [i for i in poses.registered if i in position]
    picked = [ids[int(round(x))] for x in np.linspace(0, len(ids) - 1, min(args.frames, len(ids)))]
    shift = np.eye(4)
    shift[0, 3] = source.stereo.baseline_mm  # the right eye: the left one moved along its +x
    rig = ingest.file.stereo.rig if ingest.file.stereo else None
    offset = rig.frame_offset if rig else 0  # the right frame of the same moment
    scores = []
    for i in picked:
        right = source.stereo.right(ingest.frame(i).source_index + offset)
        if right is None:
            continue
        right = resize(right, (ingest.width, ingest.height))
        right = mended_right(right, rig or RigCheck(), k).astype(np.float32) / 255.0
        with model.at_frame(position[i]):
            rgb = render_image(model, prior, k, c2w[i] @ shift, frame=position[i])["rgb"]
        usable = lens & (right.max(-1) > 0.02)  # not the right eye's black rectification band
        scores.append(losses.psnr(float(((rgb - right) ** 2).mean(-1)[usable].mean())))
        print(f"frame {i}: right eye {scores[-1]:.2f} dB", flush=True)
    held = nerf.metrics.psnr if nerf.metrics else None
    print(
        f"right eye, rendered from the left eye's field: {np.mean(scores):.2f} dB over "
        f"{len(scores)} frames; held-out left frames: {held:.2f} dB"
    )


if __name__ == "__main__":
    main()
