"""Whose reconstruction do the frames support, ours or a reference SfM's (the input's ground
truth when it is another method's: poses and the depth of its points)? Two checks on one window
of a run, keyframe by keyframe:

- our SfM points' depth against the reference's points within 1.5 px (AbsRel, median-scaled
  per frame), and our depth map's at the same points: how far the two structures disagree
  before any field, and whether the field came closer; our depth map's error at every
  reference point by the distance to our nearest SfM point (where the field is on its own);
- the reference's points of a keyframe warped into the keyframe about GAP frames later with
  (a) the reference's depth and poses, (b) our depth map at the same pixels and our poses, (c)
  no warp; median NCC of 9x9 grey patches. The better supported geometry correlates higher.

Run: `.venv/bin/python scripts/reference_check.py W/CASE/windows/w000 [--gap 8]`. The reference
depth is taken at the working size as the depth scores take it (nearest pixel). A diagnosis,
not a test.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np
from scipy.ndimage import map_coordinates
from scipy.spatial import cKDTree

from endopipe.cli import build_pipeline
from endopipe.recording.cameras import truth_poses
from endopipe.stages.camera import backproject, project

STRETCHES = [(0, 120), (120, 250), (250, 360), (360, 10**9)]
HALF = 4  # patch half-size, px


def patches(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    dy, dx = np.mgrid[-HALF : HALF + 1, -HALF : HALF + 1]
    xs, ys = x[:, None, None] + dx, y[:, None, None] + dy
    flat = map_coordinates(img, [ys.ravel(), xs.ravel()], order=1, mode="nearest")
    return flat.reshape(len(x), -1)


def ncc(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    a, b = a - a.mean(1, keepdims=True), b - b.mean(1, keepdims=True)
    return (a * b).sum(1) / np.sqrt((a * a).sum(1) * (b * b).sum(1) + 1e-9)


def scaled_errors(ours: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Each point's relative error after one median scale for the frame (the depth scores')."""
    return np.abs(np.median(reference / ours) * ours - reference) / reference


def by_stretch(rows: list[tuple], label: str) -> None:
    table = np.array(rows, dtype=np.float64)
    means = " ".join(f"{v:.3f}" for v in np.mean(table[:, 1:], 0))
    print(f"{label}: all {' '.join(f'{v:.3f}' for v in np.median(table[:, 1:], 0))} (mean {means})")
    for a, b in STRETCHES:
        sel = (table[:, 0] >= a) & (table[:, 0] < b)
        if sel.any():
            cells = " ".join(f"{v:.3f}" for v in np.median(table[sel, 1:], 0))
            print(f"  frames {a}-{min(b, int(table[:, 0].max()))}: {cells} ({int(sel.sum())})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("window", type=Path, help="a case (a recording's window) run to depth")
    parser.add_argument("--gap", type=int, default=8)
    args = parser.parse_args()
    pipe = build_pipeline()
    ingest = pipe.view(args.window, "ingest")
    poses = pipe.view(args.window, "poses")
    depth = pipe.view(args.window, "depth")
    camera = poses.intrinsics
    gt, theirs = ingest.ground_truth(), truth_poses(ingest)
    if gt is None or theirs is None:
        raise SystemExit(f"{args.window}: no reference poses and depth to check against")
    size = (camera.width, camera.height)
    source = {i: ingest.frame(i).source_index for i in poses.registered}

    def reference(i: int) -> np.ndarray:
        ref = gt.depth(source[i])
        ref = np.zeros(size[::-1], np.float32) if ref is None else ref.astype(np.float32)
        return cv2.resize(ref, size, interpolation=cv2.INTER_NEAREST)

    structure, by_distance = [], []
    obs = poses.observations(ingest.index_by_name())
    for i in poses.registered if obs is not None else []:
        ref = reference(i)
        row, col = np.nonzero(ref)
        if not len(row) or not depth.has_depth(i):
            continue
        ours = depth.depth(i)
        mine = obs.frame == i
        _, z = project(camera, obs.xyz[mine], poses.c2w[i])
        d, g = ours[row, col], ref[row, col]
        has = d > 0
        if mine.sum() >= 3 and has.sum() >= 10:
            far, _ = cKDTree(obs.uv[mine]).query(np.c_[col, row][has])
            by_distance.append(np.c_[far, scaled_errors(d[has], g[has])])
        dist, nearest = cKDTree(np.c_[col, row]).query(obs.uv[mine])
        seen = dist < 1.5  # a reference point within 1.5 px of ours
        at = row[nearest[seen]], col[nearest[seen]]
        p, g, d = z[seen], ref[at], ours[at]
        both = d > 0
        if both.sum() >= 5:
            rel = [scaled_errors(v[both], g[both]).mean() for v in (p, d)]
            structure.append((source[i], *[float(r) for r in rel]))
    label = "at the reference points ours lie near, AbsRel: our SfM points / our depth"
    by_stretch(structure, label)
    if by_distance:
        far, err = np.concatenate(by_distance).T
        print("our depth at every reference point, AbsRel by the distance to our nearest point:")
        for lo, hi in ((0, 4), (4, 8), (8, 16), (16, np.inf)):
            sel = (far >= lo) & (far < hi)
            if sel.any():
                print(f"  {lo}-{hi} px: {err[sel].mean():.3f} ({sel.mean():.0%} of the points)")

    def grey(i: int) -> np.ndarray:
        return cv2.cvtColor(ingest.image(i), cv2.COLOR_RGB2GRAY).astype(np.float32)

    rows = []
    keys = poses.registered
    for i in keys:
        later = [j for j in keys if source[j] >= source[i] + args.gap]
        if not later or not depth.has_depth(i):
            continue
        j = later[0]
        ref, ours = reference(i), depth.depth(i).astype(np.float32)
        y, x = np.nonzero((ref > 0) & (ours > 0))
        keep = (x > HALF) & (x < size[0] - HALF - 1) & (y > HALF) & (y < size[1] - HALF - 1)
        x, y = x[keep], y[keep]
        here = patches(grey(i), x.astype(float), y.astype(float))
        there = grey(j)
        scores = {}
        for name, z, ci, cj in (
            ("reference", ref, theirs[source[i]], theirs[source[j]]),
            ("ours", ours, poses.c2w[i], poses.c2w[j]),
        ):
            uv, zj = project(camera, backproject(camera, z, ci)[y, x], cj)
            inside = (zj > 0) & (uv[:, 0] > HALF) & (uv[:, 0] < size[0] - HALF - 1)
            inside &= (uv[:, 1] > HALF) & (uv[:, 1] < size[1] - HALF - 1)
            score = ncc(
                here, patches(there, np.where(inside, uv[:, 0], x), np.where(inside, uv[:, 1], y))
            )
            score[~inside] = np.nan
            scores[name] = score
        scores["no warp"] = ncc(here, patches(there, x.astype(float), y.astype(float)))
        both = np.isfinite(scores["reference"]) & np.isfinite(scores["ours"])
        if both.sum() >= 10:
            rows.append((source[i], *[float(np.median(scores[n][both])) for n in scores]))
    by_stretch(rows, f"patch NCC {args.gap} frames ahead: reference / ours / no warp")


if __name__ == "__main__":
    main()
