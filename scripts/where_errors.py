"""Where a synthetic case's remaining depth and mesh error lies (docs/results.md: the bench colon).

Run: `.venv/bin/python scripts/where_errors.py WORKDIR/runs/CASE` on a case that `endopipe
bench` (or `endopipe run` on a case folder with gt/) finished. A diagnosis, not a test:
- depth (per-frame median scaling, as the depth stage scores it): the share of the summed
  AbsRel on the pixels within 3 px of a ground-truth depth edge (a jump of over 8% between
  neighbours: fold rims) and on each frame's deepest 10% of pixels;
- mesh (the mesh stage's crop): the ground-truth points more than 0.1 radius from the mesh, how
  much of the completeness sum they carry, how much of that lies nearest the last camera (the
  end of the lumen no camera came close to), and how deep ours is there against the truth in
  the last frame.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial import cKDTree

from endopipe.stages.depth.evaluate import ground_truth_depths, inside_view
from endopipe.stages.depth.view import DepthView
from endopipe.stages.ingest.view import IngestView
from endopipe.stages.io.ground_truth import poses_by_frame
from endopipe.stages.mesh.evaluation import case_ground_truth, ground_truth_mesh
from endopipe.stages.mesh.view import MeshView
from endopipe.stages.poses.view import PosesView
from endopipe.stages.surface.evaluate import (
    faces_near_cameras,
    point_to_surface,
    sample_surface,
    visible_from_cameras,
)
from endopipe.stages.surface.mesh import read_mesh

EDGE_JUMP = 0.08  # a relative depth jump between neighbours that makes an edge
EDGE_GROW_PX = 3
DEEP_SHARE = 0.1


def depth_edges(gt: np.ndarray) -> np.ndarray:
    """Pixels within EDGE_GROW_PX of a relative jump of the truth's depth over EDGE_JUMP."""
    jump = np.zeros_like(gt)
    jump[:, 1:] = np.abs(np.diff(gt, axis=1))
    jump[1:] = np.maximum(jump[1:], np.abs(np.diff(gt, axis=0)))
    edge = (jump / np.maximum(gt, 1e-6) > EDGE_JUMP).astype(np.uint8)
    size = 2 * EDGE_GROW_PX + 1
    return cv2.dilate(edge, np.ones((size, size), np.uint8)) > 0


def depth_report(ingest: IngestView, depth: DepthView, gt) -> None:
    ids = [i for i in range(len(ingest.frames)) if depth.has_depth(i)]
    truth = ground_truth_depths(gt, ingest, ids)
    inside = inside_view(ingest)
    total = edge = deep = pixels = edge_px = 0.0
    for i, g in truth.items():
        d = depth.depth(i).astype(np.float64)
        ok = inside & (d > 0) & (g > 0)
        if not ok.any():
            continue
        s = np.median(g[ok]) / np.median(d[ok])
        err = np.abs(d[ok] * s - g[ok]) / g[ok]
        near_edge = depth_edges(g)[ok]
        deepest = g[ok] > np.quantile(g[ok], 1 - DEEP_SHARE)
        total, pixels = total + err.sum(), pixels + ok.sum()
        edge, edge_px = edge + err[near_edge].sum(), edge_px + near_edge.sum()
        deep += err[deepest].sum()
    print(
        f"depth: AbsRel {total / pixels:.4f}; {edge_px / pixels:.1%} of the pixels lie at a depth "
        f"edge and carry {edge / total:.1%} of the error; the deepest {DEEP_SHARE:.0%} carry "
        f"{deep / total:.1%}"
    )


def mesh_report(case: Path, ingest: IngestView, poses: PosesView, depth: DepthView, gt) -> None:
    view = MeshView(case / "06_mesh")
    metrics = view.metrics
    if metrics is None or not metrics.evaluated or metrics.aligned != "gt_frame":
        print("mesh: not evaluated in the truth's frame (metric poses needed)")
        return
    truth_poses = poses_by_frame(gt, ingest.frames)
    frames = [i for i in poses.registered if i in truth_poses]
    cams = [np.asarray(truth_poses[i], np.float64) for i in frames]
    truth_mesh, ours = read_mesh(ground_truth_mesh(gt)), view.load()
    k, max_depth, radius = poses.intrinsics, metrics.crop_max_depth, metrics.mean_radius
    near = faces_near_cameras(truth_mesh.vertices, truth_mesh.faces, cams, k, max_depth)
    pts = sample_surface(truth_mesh.vertices, near, 200_000, 1)
    seen = visible_from_cameras(pts, cams, k, max_depth, truth_mesh.vertices, near, ingest.fov())
    pts = pts[seen]
    dist = point_to_surface(pts, ours.vertices, ours.faces)
    missed = dist > 0.1 * radius
    _, nearest = cKDTree(np.array([c[:3, 3] for c in cams])).query(pts)
    at_end = missed & (nearest == len(cams) - 1)
    print(
        f"mesh: completeness {dist.mean():.3f} (accuracy {metrics.accuracy:.3f}); "
        f"{missed.mean():.1%} of the truth's points lie over 0.1 radius from ours and carry "
        f"{dist[missed].sum() / dist.sum():.1%} of it; {at_end.sum() / max(missed.sum(), 1):.0%} "
        "of those lie nearest the last camera"
    )
    last = frames[-1]
    g = ground_truth_depths(gt, ingest, [last]).get(last)
    d = depth.depth(last).astype(np.float64)
    if g is not None:
        far = (g > 3 * radius) & (d > 0)
        if far.any():
            print(
                f"  last frame, truth deeper than 3 radii ({far.mean():.1%} of it): ours / truth "
                f"{np.median(d[far] / g[far]):.3f} (median)"
            )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("case", type=Path)
    case = parser.parse_args().case
    ingest = IngestView(case / "01_ingest")
    gt = case_ground_truth(json.loads((case / "case.json").read_text()).get("gt_dir"))
    if gt is None:
        raise SystemExit(f"{case}: no ground truth to compare with")
    depth, poses = DepthView(case / "05_depth"), PosesView(case / "02_poses")
    depth_report(ingest, depth, gt)
    mesh_report(case, ingest, poses, depth, gt)


if __name__ == "__main__":
    main()
