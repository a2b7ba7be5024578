"""Where a trained field's albedo sits in its range, channel by channel, near and far.

Run: `.venv/bin/python scripts/albedo_range.py WORKDIR/CASE [--frame 8]` on a case run through
the nerf stage. Renders one frame, keeps the composited albedo (divided by the opacity) the
shading receives, and prints each colour channel's median and 10th percentile over the frame's
usable pixels, split at the rendered depth's 70th percentile (near / far), with the light's gain.
An albedo at its ceiling (1.0) is a channel the shading alone explains: the light's gain is too
low for it, and its texture is left to the geometry. A benchmark's probe, not a test.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from endopipe.stages.centerline.view import CenterlineView
from endopipe.stages.ingest.view import IngestView
from endopipe.stages.nerf.render import render_image
from endopipe.stages.nerf.view import NerfView
from endopipe.stages.poses.view import PosesView


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("case", type=Path)
    ap.add_argument("--frame", type=int, default=8, help="a frame the nerf stage trained on")
    args = ap.parse_args()
    ingest = IngestView(args.case / "01_ingest")
    poses = PosesView(args.case / "02_poses")
    nerf = NerfView(args.case / "04_nerf")
    prior = CenterlineView(args.case / "03_centerline").prior()
    model = nerf.model()
    k = poses.intrinsics.scaled(ingest.width, ingest.height)
    c2w = nerf.c2w(poses)
    at = {f: p for p, f in enumerate(model.meta["frame_ids"])}[args.frame]
    kept: list[torch.Tensor] = []
    shade = model.shade

    def keeping(out, albedo, *rest, **kw):
        kept.append(albedo.detach())
        return shade(out, albedo, *rest, **kw)

    model.shade = keeping
    with torch.no_grad(), model.at_frame(at):
        out = render_image(model, prior, k, c2w[at], frame=at)
    albedo = torch.cat(kept).numpy().reshape(ingest.height, ingest.width, 3)
    albedo = albedo / np.maximum(out["opacity"][..., None], 1e-6)
    usable = ingest.mask(args.frame) > 127
    far = out["depth"] > np.quantile(out["depth"][usable], 0.7)
    print(f"light gain {float(model.log_gain.detach().exp()):.3f}")
    for name, where in (("near 70%", usable & ~far), ("far 30%", usable & far)):
        a = albedo[where]
        print(
            f"{name}: albedo median R/G/B {np.round(np.median(a, 0), 3)}, 10th percentile "
            f"{np.round(np.quantile(a, 0.1, axis=0), 3)}, at the ceiling (> 0.95) "
            f"{np.round((a > 0.95).mean(0), 3)}"
        )


if __name__ == "__main__":
    main()
