"""Which pairing of a rig's left and right frames sees one instant, and what a reference depth
made on the other pairing is worth as a truth.

Two ingests of the same stereo input: the run's (the rig check's pairing) and another paired
as named (`endopipe run INPUT --workdir W2 --until ingest --set ingest.stereo.max_offset=0`).
For each, frame by frame:

- its stereo depth over the run's SfM points' depth (the poses and points come from the left
  eye alone, across frames): the pairing that sees one instant holds a steady ratio; one that
  mixes two instants swings with the camera's sideways motion;
- its agreement with the input's reference depth (`gt/` or the data set's, e.g. Hamlyn's
  depth01): AbsRel median-scaled per frame, and at one scale for the whole sequence;
- the two pairings' disparity difference (px at the working size) against the left eye's own
  sideways image motion since the previous frame (phase correlation): slope 1 says the named
  right frame is one frame behind.

Run: `.venv/bin/python scripts/stereo_pairing.py W/CASE W2/CASE`. A diagnosis, not a test.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from endopipe.cli import build_pipeline
from endopipe.stages.io.ground_truth import depth_of_frame


def grey(ingest, i: int) -> np.ndarray:
    return cv2.cvtColor(ingest.image(i), cv2.COLOR_RGB2GRAY).astype(np.float32)


def sfm_ratio(ingest, poses, obs, i: int) -> float | None:
    """Median of the stereo depth over the SfM points' depth in frame i."""
    depth = ingest.stereo_depth(i)
    sel = obs.frame == i
    if depth is None or sel.sum() < 20:
        return None
    c2w = poses.c2w[i]
    z = ((obs.xyz[sel] - c2w[:3, 3]) @ c2w[:3, :3])[:, 2]
    u, v = np.rint(obs.uv[sel]).astype(int).T
    inside = (u >= 0) & (u < depth.shape[1]) & (v >= 0) & (v < depth.shape[0])
    d = depth[v[inside], u[inside]]
    ok = d > 0
    return float(np.median(d[ok] / z[inside][ok])) if ok.sum() >= 20 else None


def truth_scores(ingest, gt, ids: list[int]) -> tuple[float, float]:
    """(mean per-frame median-scaled AbsRel, AbsRel at one scale for the sequence)."""
    per, pairs = [], []
    for i in ids:
        ours, ref = ingest.stereo_depth(i), depth_of_frame(gt, ingest.frame(i))
        if ours is None or ref is None:
            continue
        if ref.shape != ours.shape:
            ref = cv2.resize(ref, ours.shape[::-1], interpolation=cv2.INTER_NEAREST)
        ok = (ours > 0) & (ref > 0)
        d, g = ours[ok], ref[ok]
        s = np.median(g / d)
        per.append(np.mean(np.abs(s * d - g) / g))
        pairs.append((d, g))
    scale = np.median(np.concatenate([g / d for d, g in pairs]))
    one = np.mean(np.concatenate([np.abs(scale * d - g) / g for d, g in pairs]))
    return float(np.mean(per)), float(one)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path, help="the case folder as run (its poses are used)")
    ap.add_argument("other", type=Path, help="the same input's ingest paired the other way")
    args = ap.parse_args()
    views = {s.name: s.View for s in build_pipeline().stages}
    poses = views["poses"](args.run / "02_poses")
    runs = {p: views["ingest"](p / "01_ingest") for p in (args.run, args.other)}
    first = runs[args.run]
    obs = poses.observations(first.index_by_name())
    k = poses.intrinsics
    if obs is not None and (k.width, k.height) != (first.width, first.height):
        obs.resize((k.width, k.height), (first.width, first.height))
    gt = first.ground_truth()
    ids = [i for i in first.indices if all(r.has_frame(i) for r in runs.values())]
    for path, ingest in runs.items():
        rig = ingest.file.stereo.rig if ingest.file.stereo else None
        offset = rig.frame_offset if rig else 0
        line = f"{path}: right frame {offset:+d}"
        if obs is not None:
            r = np.array([x for i in ids if (x := sfm_ratio(ingest, poses, obs, i)) is not None])
            line += (
                f"; stereo / SfM depth per frame: median {np.median(r):.3f}, spread (std/mean) "
                f"{r.std() / r.mean():.4f}, 5-95% {np.percentile(r, 5):.3f}-"
                f"{np.percentile(r, 95):.3f}"
            )
        if gt is not None:
            per, one = truth_scores(ingest, gt, ids)
            line += f"; against the reference: {per:.4f} median-scaled, {one:.4f} at one scale"
        print(line)
    a, b = runs.values()
    fx_b = first.file.intrinsics.fx * (first.file.stereo.baseline_mm or 1.0)
    diff, motion = [], []
    for prev, i in zip(ids, ids[1:], strict=False):
        da, db = a.stereo_depth(i), b.stereo_depth(i)
        if da is None or db is None or ((da > 0) & (db > 0)).sum() < 1000:
            continue
        ok = (da > 0) & (db > 0)
        diff.append(np.median(fx_b / db[ok] - fx_b / da[ok]))
        window = cv2.createHanningWindow(da.shape[::-1], cv2.CV_32F)
        motion.append(cv2.phaseCorrelate(grey(first, prev), grey(first, i), window)[0][0])
    slope, _ = np.polyfit(motion, diff, 1)
    print(
        f"disparity (other - run's) against the left eye's sideways motion since the previous "
        f"frame, {len(diff)} frames: correlation {np.corrcoef(diff, motion)[0, 1]:.3f}, slope "
        f"{slope:.2f} px per px; the difference {np.min(diff):.2f} to {np.max(diff):.2f} px"
    )


if __name__ == "__main__":
    main()
