"""A hand-made case folder, written the way the stages would write it, without running them.

Cameras move along +z looking at a wall (the plane z = WALL_Z), so ground-truth depth is
analytic. Used by test_export.py, whose tests need exact, known geometry; the report's tests
use the real output of a tiny end-to-end run instead (the `tiny_case` fixture).
"""

from __future__ import annotations

import hashlib
import time
from pathlib import Path

import cv2
import numpy as np
import trimesh

from endopipe.pipeline.cache import Manifest, list_files
from endopipe.pipeline.stage import CaseInfo, write_json
from endopipe.stages.camera import Camera
from endopipe.stages.centerline.summary import CenterlineSummary
from endopipe.stages.depth.summary import DepthSummary
from endopipe.stages.ingest.summary import IngestSummary
from endopipe.stages.mesh.summary import MeshSummary
from endopipe.stages.nerf.summary import NerfSummary
from endopipe.stages.poses.summary import PosesSummary
from endopipe.stages.poses.view import CamerasFile

W, H = 64, 48
N_FRAMES = 6
UNREGISTERED = 4
WALL_Z = 40.0
#: 05_depth/metrics.json as the depth stage writes it (stages.metrics.depth_sequence_metrics).
DEPTH_METRICS = {
    "median_scaled": {
        "abs_rel": 0.0523,
        "sq_rel": 0.11,
        "rmse": 1.93,
        "rmse_log": 0.071,
        "delta1": 0.971,
        "delta2": 0.995,
        "delta3": 0.999,
    },
    "sequence_scaled": {
        "abs_rel": 0.0687,
        "sq_rel": 0.16,
        "rmse": 2.41,
        "rmse_log": 0.089,
        "delta1": 0.952,
        "delta2": 0.991,
        "delta3": 0.998,
        "scale": 1.02,
    },
    "frames": 5,
    "per_frame": [
        {"index": i, "median_scaled": {"abs_rel": a}, "sequence_scaled": {"abs_rel": b}}
        for i, a, b in ((0, 0.05, 0.07), (1, 0.06, 0.08), (2, 0.04, 0.06), (3, 0.05, 0.06))
    ],
    "gt_kind": "exact",
    "heldout_frames": [0],
    "heldout_psnr": 23.4,
    "heldout_ssim": 0.812,
}
#: 06_mesh/metrics.json as the mesh stage writes it.
MESH_METRICS = {
    "evaluated": True,
    "chamfer": 0.842,
    "chamfer_pct_radius": 14.03,
    "accuracy": 0.8,
    "completeness": 0.884,
    "precision": 0.93,
    "recall": 0.897,
    "fscore": 0.913,
    "threshold": 1.0,
    "aligned": "gt_frame",
    "sim3_scale": 1.0,
}


def _rot_y(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])


def camera_poses(n: int = N_FRAMES) -> list[np.ndarray]:
    """OpenCV c2w: cameras advancing along +z, wobbling, turning a little about y."""
    poses = []
    for i in range(n):
        c2w = np.eye(4)
        c2w[:3, :3] = _rot_y(4.0 * np.sin(i)) @ _rot_y(-3.0)
        c2w[:3, 3] = [0.8 * np.sin(i), 0.5 * np.cos(i), 2.0 * i]
        poses.append(c2w)
    return poses


def wall_depth(k: Camera, c2w: np.ndarray, wall_z: float = WALL_Z) -> np.ndarray:
    """z-depth of the plane z = wall_z seen by the camera c2w (float32, H x W)."""
    u, v = np.meshgrid(np.arange(k.width), np.arange(k.height))
    rays = np.stack([(u - k.cx) / k.fx, (v - k.cy) / k.fy, np.ones_like(u, float)], -1)
    world_dz = rays @ c2w[:3, :3].T
    return ((wall_z - c2w[2, 3]) / world_dz[..., 2]).astype(np.float32)


def _manifest(folder: Path, stage: str, wall: float, rss: float, summary: dict) -> None:
    now = time.time()
    m = Manifest(
        stage=stage,
        key=hashlib.sha256(stage.encode()).hexdigest(),
        version=1,
        config={"example": True},
        upstream={},
        started=now - wall,
        finished=now,
        wall_s=wall,
        peak_rss_mb=rss,
        summary=summary,
        files=list_files(folder),
    )
    (folder / "manifest.json").write_text(m.model_dump_json(indent=2))


def make_case(
    root: Path,
    *,
    gt: bool = True,
    stages: tuple[str, ...] = ("ingest", "poses", "centerline", "nerf", "depth", "mesh"),
    metrics: bool = True,
    sparse: bool = False,
    camera_scale: int = 1,
    video: bool = False,
) -> Path:
    """A case folder as the pipeline would leave it (only the listed stages)."""
    rng = np.random.default_rng(0)
    case = root / "case"
    case.mkdir(parents=True)
    k = Camera(width=W, height=H, fx=50.0, fy=52.0, cx=31.0, cy=24.5)
    poses = camera_poses()
    gt_dir = root / "input" / "gt"
    if gt:
        (gt_dir / "depth").mkdir(parents=True)
        for i, c2w in enumerate(poses):
            np.save(gt_dir / "depth" / f"{i:06d}.npy", wall_depth(k, c2w))
        write_json(
            gt_dir / "poses.json",
            {"convention": "opencv_c2w", "units": "mm", "poses": [p.tolist() for p in poses]},
        )
    info = CaseInfo(
        name="case",
        input=str(root / "input"),
        kind="case",
        input_digest="0" * 64,
        gt_dir=str(gt_dir) if gt else None,
    )
    write_json(case / "case.json", info.model_dump())

    if "ingest" in stages:
        d = case / "01_ingest"
        (d / "frames").mkdir(parents=True)
        (d / "masks").mkdir()
        entries = []
        for i in range(N_FRAMES):
            img = cv2.resize(rng.integers(40, 220, (6, 8, 3), dtype=np.uint8), (W, H))
            cv2.imwrite(str(d / "frames" / f"{i:06d}.png"), img)
            mask = np.full((H, W), 255, np.uint8)
            mask[:6, :6] = 0  # a masked corner
            cv2.imwrite(str(d / "masks" / f"{i:06d}.png"), mask)
            entries.append(
                {
                    "index": i,
                    "source_index": i,
                    "time_s": i / 10,
                    "file": f"frames/{i:06d}.png",
                    "mask": f"masks/{i:06d}.png",
                }
            )
        cv2.imwrite(str(d / "contact_sheet.png"), np.full((H * 2, W * 3, 3), 128, np.uint8))
        write_json(
            d / "frames.json",
            {
                "frames": entries,
                "intrinsics": k.model_dump(),
                "width": W,
                "height": H,
                "gt_dir": str(gt_dir) if gt else None,
            },
        )
        ingest_summary = IngestSummary(
            kind="case",
            source_frames=N_FRAMES,
            read=N_FRAMES,
            kept=N_FRAMES,
            dropped={},
            width=W,
            height=H,
            fov_shape="full",
            fov_fraction=1.0,
            mean_specular_fraction=0.0,
            has_intrinsics=True,
            has_ground_truth=gt,
        )
        _manifest(d, "ingest", 1.2, 310.0, ingest_summary.model_dump(mode="json"))

    if "poses" in stages:
        d = case / "02_poses"
        d.mkdir()
        kc = k.scaled(W * camera_scale, H * camera_scale)
        registered = {i: p for i, p in enumerate(poses) if i != UNREGISTERED}
        cams = CamerasFile.build(kc, registered, N_FRAMES, metric=gt, source="test")
        write_json(d / "cameras.json", cams.model_dump(mode="json"))
        if sparse:
            from endopipe.stages.io.colmap_model import write_text_model

            write_text_model(
                d / "sparse",
                kc,
                {f"{i:06d}.png": p for i, p in registered.items()},
            )
        poses_summary = PosesSummary(
            source="gt" if gt else "file",
            registered=len(registered),
            total=N_FRAMES,
            registered_fraction=len(registered) / N_FRAMES,
            unregistered=str(UNREGISTERED),
            camera_model="PINHOLE",
            intrinsics="fixed",
            fx=k.fx,
            fy=k.fy,
            cx=k.cx,
            cy=k.cy,
            metric=gt,
            aligned_to_gt=gt,
            points=0,
            seconds=3.4,
            **({"ate_mm": 0.42, "ate_percent_of_path": 4.2, "rre_deg": 0.31} if gt else {}),
        )
        _manifest(d, "poses", 3.4, 420.0, poses_summary.model_dump(mode="json"))

    if "centerline" in stages:
        d = case / "03_centerline"
        d.mkdir()
        z = np.linspace(-2, 14, 20)
        pts = np.stack([np.zeros_like(z), np.zeros_like(z), z], 1)
        write_json(
            d / "centerline.json",
            {
                "kind": "tube",
                "units": "mm",
                "points": pts.tolist(),
                "radius": np.full(20, 6.0).tolist(),
                "arclength": (z - z[0]).tolist(),
                "camera_span": [2.0, 12.0],
                "radius_source": "points",
            },
        )
        cv2.imwrite(str(d / "centerline.png"), np.full((40, 60, 3), 200, np.uint8))
        centerline_summary = CenterlineSummary(
            kind="tube",
            length=16.0,
            mean_radius=6.0,
            radius_source="points",
            radius_note="",
            n_points_used=0,
            n_cameras=N_FRAMES - 1,
            units="mm",
        )
        _manifest(d, "centerline", 0.8, 300.0, centerline_summary.model_dump(mode="json"))

    if "nerf" in stages:
        d = case / "04_nerf"
        d.mkdir()
        rows = ["step,loss,photo,prior,psnr"] + [
            f"{s},{0.2 * np.exp(-s / 50) + 0.01:.5f},{0.15 * np.exp(-s / 50):.5f},,"
            f"{14 + 8 * (1 - np.exp(-s / 60)):.3f}"
            for s in range(0, 201, 20)
        ]
        (d / "train_log.csv").write_text("\n".join(rows) + "\n")
        (d / "model.pt").write_bytes(b"not a real model")
        if metrics:
            write_json(d / "metrics.json", {"psnr": 23.4, "render_ms": 12.0})
        nerf_summary = NerfSummary(
            steps=200,
            train_frames=N_FRAMES - 2,
            heldout_frames=1,
            train_s=95.0,
            rays_per_s=4000.0,
            heldout_psnr=23.4,
        )
        _manifest(d, "nerf", 95.0, 1800.0, nerf_summary.model_dump(mode="json"))

    if "depth" in stages:
        d = case / "05_depth"
        (d / "depth").mkdir(parents=True)
        for i, c2w in enumerate(poses):
            if i == UNREGISTERED:
                continue
            depth = wall_depth(k, c2w)
            depth[-3:, -3:] = 0  # invalid pixels
            np.save(d / "depth" / f"{i:06d}.npy", depth)
        if metrics and gt:
            write_json(d / "metrics.json", DEPTH_METRICS)
        if video:
            from tests.conftest import write_video

            write_video(d / "preview.mp4", [np.full((H, W * 3, 3), 90, np.uint8)] * 3)
        depth_summary = DepthSummary(
            frames=N_FRAMES - 1,
            units="mm",
            png_scale=1000.0,
            ms_per_frame=20.0,
            bake_s=1.0,
            renderer="baked",
        )
        _manifest(d, "depth", 12.5, 900.0, depth_summary.model_dump(mode="json"))

    if "mesh" in stages:
        d = case / "06_mesh"
        d.mkdir()
        mesh = trimesh.creation.cylinder(radius=6.0, height=16.0, sections=48)
        mesh.apply_translation([0, 0, 6.0])
        mesh.export(d / "mesh.ply")
        if metrics and gt:
            write_json(d / "metrics.json", MESH_METRICS)
        mesh_summary = MeshSummary(
            method="tsdf",
            vertices=len(mesh.vertices),
            faces=len(mesh.faces),
            voxel_size=0.25,
            depth_trunc=60.0,
            frames_used=N_FRAMES - 1,
            units="mm",
            build_s=3.0,
            clean_s=1.0,
        )
        _manifest(d, "mesh", 4.0, 500.0, mesh_summary.model_dump(mode="json"))
    return case
