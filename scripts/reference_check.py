"""Whose reconstruction do the frames support, ours or a reference SfM's (a case folder's gt/:
poses and the depth of its points)? Two checks on one window of a run, keyframe by keyframe:

- our SfM points' depth against the reference's points within 1.5 px (AbsRel, median-scaled
  per frame): how far the two structures disagree before any field;
- the reference's points of a keyframe warped into the keyframe about GAP frames later with
  (a) the reference's depth and poses, (b) our depth map at the same pixels and our poses, (c)
  no warp; median NCC of 9x9 grey patches. The better supported geometry correlates higher.

Run: `.venv/bin/python scripts/reference_check.py W/CASE/windows/w000 CASE_FOLDER [--gap 8]`.
A diagnosis, not a test.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np
import pycolmap
from scipy.ndimage import map_coordinates
from scipy.spatial import cKDTree

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


def by_stretch(rows: list[tuple], label: str) -> None:
    table = np.array(rows, dtype=np.float64)
    print(f"{label}: all {' '.join(f'{v:.3f}' for v in np.median(table[:, 1:], 0))}")
    for a, b in STRETCHES:
        sel = (table[:, 0] >= a) & (table[:, 0] < b)
        if sel.any():
            cells = " ".join(f"{v:.3f}" for v in np.median(table[sel, 1:], 0))
            print(f"  frames {a}-{min(b, int(table[:, 0].max()))}: {cells} ({int(sel.sum())})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("window", type=Path)
    parser.add_argument("case", type=Path, help="the case folder with gt/poses.json, gt/depth/")
    parser.add_argument("--gap", type=int, default=8)
    args = parser.parse_args()
    ingest = json.loads((args.window / "01_ingest" / "frames.json").read_text())
    w, h, k = ingest["width"], ingest["height"], ingest["intrinsics"]
    fx, fy, cx, cy = k["fx"], k["fy"], k["cx"], k["cy"]
    source = {f["index"]: f["source_index"] for f in ingest["frames"]}
    index = {s: i for i, s in source.items()}
    theirs = json.loads((args.case / "gt" / "poses.json").read_text())["poses"]
    theirs = [np.array(p) for p in theirs]
    rec = pycolmap.Reconstruction(str(args.window / "02_poses" / "sparse"))
    ours: dict[int, np.ndarray] = {}
    structure = []
    for image in rec.images.values():
        if not image.has_pose:
            continue
        s = source[int(Path(image.name).stem)]
        w2c = np.eye(4)
        w2c[:3] = image.cam_from_world().matrix()
        ours[s] = np.linalg.inv(w2c)
        seen = [p for p in image.points2D if p.has_point3D()]
        ref = np.load(args.case / "gt" / "depth" / f"{s:06d}.npy")
        v, u = np.nonzero(ref)
        if not seen or not len(v):
            continue
        xy = np.array([p.xy for p in seen]) - 0.5  # COLMAP's pixel centres sit at +0.5
        xyz = np.array([rec.points3D[p.point3D_id].xyz for p in seen])
        z = (xyz @ w2c[:3, :3].T + w2c[:3, 3])[:, 2]
        gx = (u + 0.5) * w / ref.shape[1] - 0.5
        gy = (v + 0.5) * h / ref.shape[0] - 0.5
        dist, j = cKDTree(np.c_[gx, gy]).query(xy)
        near = dist < 1.5
        if near.sum() >= 5:
            p, g = z[near], ref[v[j[near]], u[j[near]]]
            scale = np.median(g / p)
            structure.append((s, float(np.mean(np.abs(scale * p - g) / g))))
    by_stretch(structure, "our SfM points against the reference's, AbsRel")

    def grey(s: int) -> np.ndarray:
        image = cv2.imread(str(args.case / "frames" / f"{s:06d}.jpg"), cv2.IMREAD_GRAYSCALE)
        return cv2.resize(image, (w, h), interpolation=cv2.INTER_AREA).astype(np.float32)

    def warp(x, y, z, ci, cj):
        cam = np.c_[(x - cx) / fx * z, (y - cy) / fy * z, z]
        world = cam @ ci[:3, :3].T + ci[:3, 3]
        wj = np.linalg.inv(cj)
        other = world @ wj[:3, :3].T + wj[:3, 3]
        return fx * other[:, 0] / other[:, 2] + cx, fy * other[:, 1] / other[:, 2] + cy, other[:, 2]

    rows = []
    keys = sorted(ours)
    for s in keys:
        later = [t for t in keys if t >= s + args.gap]
        if not later:
            break
        t = later[0]
        ref = np.load(args.case / "gt" / "depth" / f"{s:06d}.npy")
        v, u = np.nonzero(ref)
        x = (u + 0.5) * w / ref.shape[1] - 0.5
        y = (v + 0.5) * h / ref.shape[0] - 0.5
        z_ref = ref[v, u]
        depth = np.load(args.window / "05_depth" / "depth" / f"{index[s]:06d}.npy")
        z_ours = map_coordinates(depth.astype(np.float32), [y, x], order=0)
        keep = (x > HALF) & (x < w - HALF - 1) & (y > HALF) & (y < h - HALF - 1) & (z_ours > 0)
        x, y, z_ref, z_ours = x[keep], y[keep], z_ref[keep], z_ours[keep]
        a, b = grey(s), grey(t)
        here = patches(a, x, y)
        scores = {}
        for name, z, ci, cj in (
            ("reference", z_ref, theirs[s], theirs[t]),
            ("ours", z_ours, ours[s], ours[t]),
        ):
            xj, yj, zj = warp(x, y, z, ci, cj)
            inside = (
                (zj > 0) & (xj > HALF) & (xj < w - HALF - 1) & (yj > HALF) & (yj < h - HALF - 1)
            )
            score = ncc(here, patches(b, np.where(inside, xj, x), np.where(inside, yj, y)))
            score[~inside] = np.nan
            scores[name] = score
        scores["no warp"] = ncc(here, patches(b, x, y))
        both = np.isfinite(scores["reference"]) & np.isfinite(scores["ours"])
        if both.sum() >= 10:
            rows.append((s, *[float(np.median(scores[n][both])) for n in scores]))
    by_stretch(rows, f"patch NCC {args.gap} frames ahead: reference / ours / no warp")


if __name__ == "__main__":
    main()
