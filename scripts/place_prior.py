"""Put one case's lumen prior into another case of the same input (a recording's window), moved
by the similarity fitted on the cameras both registered: to measure what the window's own
prior costs it. The target's `03_centerline/prior.npz` is replaced and listed in that stage's
manifest (the cache keeps the stage, with the placed prior); run the target again from the NeRF
(`endopipe run TARGET --from nerf`) and compare its depth score.

Run on a copy of the window, never on the original:
`cp -r W/windowed/windows/w000 W/w000_placed && .venv/bin/python scripts/place_prior.py
W/w000_placed W/single && endopipe run W/w000_placed --from nerf`. An experiment, not a test.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from endopipe.cli import build_pipeline
from endopipe.pipeline.cache import MANIFEST, Manifest, list_files
from endopipe.recording.cameras import cameras_by_source
from endopipe.recording.join import fit_similarity, junction_error_pct
from endopipe.stages.centerline.prior import load_prior, save_prior


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("target", type=Path, help="the case whose prior is replaced (a copy)")
    parser.add_argument("source", type=Path, help="the case whose prior it takes")
    args = parser.parse_args()
    pipe = build_pipeline()
    to, frm = cameras_by_source(pipe, args.target), cameras_by_source(pipe, args.source)
    shared = sorted(set(to) & set(frm))
    if len(shared) < 3:
        raise SystemExit(f"the cases share {len(shared)} registered frames; at least 3 needed")
    a, b = [to[i] for i in shared], [frm[i] for i in shared]
    sim = fit_similarity(a, b)  # source -> target
    folder = args.target / "03_centerline"
    manifest = Manifest.load(folder)
    if manifest is None:
        raise SystemExit(f"{folder} holds no finished centerline stage")
    prior = load_prior(args.source / "03_centerline" / "prior.npz")
    save_prior(prior.moved(sim.s, np.array(sim.R), np.array(sim.t)), folder / "prior.npz")
    manifest.files = list_files(folder)
    (folder / MANIFEST).write_text(manifest.model_dump_json(indent=2))
    print(
        f"{args.source}'s {prior.kind} placed in {args.target} (scale {sim.s:.3f}; the "
        f"{len(shared)} shared cameras {junction_error_pct(a, b, sim):.2f}% of the path apart)"
    )


if __name__ == "__main__":
    main()
