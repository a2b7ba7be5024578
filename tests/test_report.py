"""report: the self-contained HTML page, built on small hand-made stage folders.

`make_case` writes a case the way the stages would (frames.json, cameras.json via CamerasFile,
depth .npy, a mesh, metrics, manifests) without running them: cameras move along +z looking at
a wall (the plane z = WALL_Z), so ground-truth depth is analytic. test_export.py uses it too.
"""

from __future__ import annotations

import hashlib
import re
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
import trimesh
from rich.console import Console

from endopipe.pipeline.cache import Manifest, list_files
from endopipe.pipeline.stage import CaseInfo, StageContext, write_json
from endopipe.stages.camera import Camera
from endopipe.stages.poses.view import CamerasFile
from endopipe.stages.report.stage import (
    Report,
    ReportConfig,
    build_report,
    decimate,
    page_is_self_contained,
    per_frame_series,
    render_report,
)

W, H = 64, 48
N_FRAMES = 6
UNREGISTERED = 4
WALL_Z = 40.0
STAGE_FOLDERS = {
    "ingest": "01_ingest",
    "poses": "02_poses",
    "centerline": "03_centerline",
    "nerf": "04_nerf",
    "depth": "05_depth",
    "mesh": "06_mesh",
}
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
#: The same, in the key names of the issue text (global_scaled, psnr, ssim, per_frame lists).
DEPTH_METRICS_ALT = {
    "median_scaled": DEPTH_METRICS["median_scaled"],
    "global_scaled": DEPTH_METRICS["sequence_scaled"],
    "psnr": 23.4,
    "ssim": 0.812,
    "per_frame": {
        "index": [0, 1, 2, 3, 5],
        "median_scaled": {"abs_rel": [0.05, 0.06, 0.04, 0.05, 0.06]},
        "global_scaled": {"abs_rel": [0.07, 0.08, 0.06, 0.06, 0.07]},
    },
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
        _manifest(d, "ingest", 1.2, 310.0, {"kept": N_FRAMES, "source_frames": N_FRAMES})

    if "poses" in stages:
        d = case / "02_poses"
        d.mkdir()
        kc = k.scaled(W * camera_scale, H * camera_scale)
        registered = {i: p for i, p in enumerate(poses) if i != UNREGISTERED}
        cams = CamerasFile.build(kc, registered, N_FRAMES, metric=gt, source="test")
        write_json(d / "cameras.json", cams.model_dump(mode="json"))
        if sparse:
            from endopipe.stages.io.colmap_model import CameraModel, write_text_model

            write_text_model(
                d / "sparse",
                CameraModel.pinhole(kc),
                {f"{i:06d}.png": p for i, p in registered.items()},
            )
        summary = {
            "source": "test",
            "registered": len(registered),
            "total": N_FRAMES,
            "registered_fraction": len(registered) / N_FRAMES,
            "metric": gt,
        }
        if gt:
            summary.update(ate_mm=0.42, ate_percent_of_path=4.2, rre_deg=0.31)
        _manifest(d, "poses", 3.4, 420.0, summary)

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
        _manifest(d, "centerline", 0.8, 300.0, {"kind": "tube", "length": 16.0})

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
        _manifest(d, "nerf", 95.0, 1800.0, {"steps": 200, "heldout_psnr": 23.4})

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
        _manifest(d, "depth", 12.5, 900.0, {"frames": N_FRAMES - 1})

    if "mesh" in stages:
        d = case / "06_mesh"
        d.mkdir()
        mesh = trimesh.creation.cylinder(radius=6.0, height=16.0, sections=48)
        mesh.apply_translation([0, 0, 6.0])
        mesh.export(d / "mesh.ply")
        if metrics and gt:
            write_json(d / "metrics.json", MESH_METRICS)
        _manifest(d, "mesh", 4.0, 500.0, {"vertices": len(mesh.vertices)})
    return case


#: A cheaper config for tests that are not about the previews.
FAST = ReportConfig(max_preview_frames=1, mesh_views=1)


def folders_of(case: Path) -> dict[str, Path]:
    return {name: case / folder for name, folder in STAGE_FOLDERS.items()}


@pytest.fixture
def full_case(tmp_path: Path) -> Path:
    return make_case(tmp_path, video=True)


# --- content ----------------------------------------------------------------------------------


def test_full_report_has_every_section_and_metric(full_case: Path) -> None:
    page, info = render_report(full_case, folders_of(full_case), ReportConfig())
    assert all(info.sections.values()), info.sections
    assert info.gt_kind == "exact"
    assert info.mesh_viewer.startswith("three.js")
    for text in (
        "Summary",
        "per-frame median scaling",
        "one scale for the sequence",
        "0.0523",  # AbsRel, median scaling
        "0.0687",  # AbsRel, one global scale
        "0.812",  # SSIM
        "23.4",  # PSNR
        "0.842",  # Chamfer
        "0.913",  # F-score
        "ATE",
        "14.03",  # Chamfer as % of the radius
        "at 1 mm",  # F-score threshold
        "5 of 6 frames",  # registered ratio
        "metric (mm)",
        "exact",
        "data:video/mp4;base64,",
        "<iframe",
    ):
        assert text in page, text
    # one wall-time row per stage, from the manifests
    for stage, wall in (("ingest", "1.2 s"), ("nerf", "1 min 35 s"), ("mesh", "4.0 s")):
        assert re.search(rf"<b>{stage}</b>.*?{re.escape(wall)}", page, re.S), stage
    assert "1,800 MB" in page  # nerf's peak memory


def test_report_reads_the_alternative_key_names(tmp_path: Path) -> None:
    case = make_case(tmp_path)
    write_json(case / "05_depth" / "metrics.json", DEPTH_METRICS_ALT)
    page = build_report(case, folders_of(case), FAST)
    for text in ("0.0523", "0.0687", "0.812", "23.4", "one scale for the sequence"):
        assert text in page, text
    assert "AbsRel per frame" in page


def test_mesh_not_evaluated_shows_the_reason(tmp_path: Path) -> None:
    case = make_case(tmp_path)
    write_json(
        case / "06_mesh" / "metrics.json",
        {"evaluated": False, "reason": "cameras not metric and fewer than 3 GT poses"},
    )
    page = build_report(case, folders_of(case), FAST)
    assert "not evaluated: cameras not metric and fewer than 3 GT poses" in page


def test_report_is_self_contained(full_case: Path) -> None:
    page = build_report(full_case, folders_of(full_case))
    assert page_is_self_contained(page)
    # nothing is fetched: every src / href is a data URI or an in-page anchor
    for attr in re.findall(r"""\b(?:src|href)\s*=\s*["']([^"']*)""", page):
        assert attr.startswith(("data:", "#")), attr[:80]
    # the viewer inside the iframe carries three.js itself
    import html

    srcdoc = html.unescape(re.search(r'srcdoc="([^"]*)"', page).group(1))
    assert page_is_self_contained(srcdoc)
    assert "WebGLRenderer" in srcdoc and "GLTFLoader" in srcdoc
    assert len(page) < 8 * 2**20


def test_report_degrades_without_gt_and_downstream_stages(tmp_path: Path) -> None:
    case = make_case(tmp_path, gt=False, stages=("ingest", "poses"))
    page, info = render_report(case, folders_of(case), ReportConfig())
    assert info.gt_kind == "none"
    assert info.mesh_viewer == "none"
    assert info.sections["summary"] and info.sections["stages"]
    assert not info.sections["depth"] and not info.sections["mesh"]
    assert page.count("Not available") >= 3
    assert "No ground truth" in page
    assert "arbitrary" in page  # not metric


def test_report_says_which_metrics_are_missing(tmp_path: Path) -> None:
    case = make_case(tmp_path, metrics=False)
    page, info = render_report(
        case, folders_of(case), FAST.model_copy(update={"include_mesh_viewer": False})
    )
    assert "05_depth/metrics.json is missing" in page
    assert "06_mesh/metrics.json is missing" in page
    assert info.mesh_viewer == "static"
    assert "<iframe" not in page


def test_broken_artefacts_do_not_break_the_page(tmp_path: Path) -> None:
    case = make_case(tmp_path)
    (case / "06_mesh" / "mesh.ply").write_bytes(b"ply\nformat nonsense\n")
    (case / "05_depth" / "metrics.json").write_text("{not json")
    (case / "04_nerf" / "manifest.json").write_text("[]")
    np.save(case / "05_depth" / "depth" / "000000.npy", np.zeros((3,), np.float32))  # wrong shape
    page, info = render_report(case, folders_of(case), FAST)
    assert "mesh.ply unreadable" in page
    assert "Not available" in page
    assert "</html>" in page.rstrip()[-10:]
    assert info.sections["summary"]


def test_report_stage_writes_one_html_file(tmp_path: Path) -> None:
    case = make_case(tmp_path)
    out = case / ".07_report.tmp"
    out.mkdir()
    ctx = StageContext(
        case_dir=case,
        out=out,
        config=ReportConfig(max_preview_frames=2, mesh_views=1),
        case=CaseInfo.load(case),
        inputs=folders_of(case),
        resolve_view=lambda name, folder: folder,
        console=Console(quiet=True),
        quiet=True,
    )
    summary = Report().run(ctx)
    assert [p.name for p in out.iterdir()] == ["report.html"]
    assert summary.gt_kind == "exact" and 0 < summary.size_mb < 8
    assert Report.needs == ("ingest", "poses", "centerline", "nerf", "depth", "mesh")
    with pytest.raises(ValueError):
        ReportConfig(unknown_key=1)


def test_decimate_keeps_the_shape_under_the_face_budget() -> None:
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=10.0)  # 20480 faces
    colours = np.tile([200, 100, 50], (len(sphere.vertices), 1)).astype(np.uint8)
    v, f, c = decimate(sphere.vertices, sphere.faces, 2000, colours)
    assert 500 < len(f) <= 2000
    assert f.max() < len(v) and c.shape == (len(v), 3)
    assert np.allclose(np.linalg.norm(v, axis=1), 10.0, atol=0.6)
    assert np.all(c == [200, 100, 50])
    same = decimate(sphere.vertices, sphere.faces, 10**6)
    assert len(same[1]) == len(sphere.faces)


def test_per_frame_series_accepts_the_usual_shapes() -> None:
    by_proto = per_frame_series(DEPTH_METRICS_ALT["per_frame"])
    assert by_proto["per-frame median scaling"] == ([0, 1, 2, 3, 5], [0.05, 0.06, 0.04, 0.05, 0.06])
    listed = per_frame_series(DEPTH_METRICS["per_frame"])
    assert listed["one scale for the sequence"] == ([0, 1, 2, 3], [0.07, 0.08, 0.06, 0.06])
    rows = [{"index": 3, "abs_rel": 0.1}, {"index": 7, "abs_rel": 0.2}]
    assert per_frame_series(rows) == {"per frame": ([3, 7], [0.1, 0.2])}
    nested = [{"index": 1, "median_scaled": {"abs_rel": 0.3}}]
    assert per_frame_series(nested)["per-frame median scaling"] == ([1], [0.3])
    assert per_frame_series(None) == {}


# --- a real browser ------------------------------------------------------------------------------

CHROMIUM = next(
    (shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome") if shutil.which(n)),
    None,
)


@pytest.mark.skipif(
    CHROMIUM is None,
    reason="no headless browser: install Debian's `chromium` package (apt-get install chromium)",
)
def test_report_renders_in_headless_chromium(full_case: Path, tmp_path: Path) -> None:
    page = tmp_path / "report.html"
    page.write_text(build_report(full_case, folders_of(full_case)), encoding="utf-8")
    shot = tmp_path / "screenshot.png"
    with tempfile.TemporaryDirectory() as profile:
        proc = subprocess.run(
            [
                CHROMIUM,
                "--headless",
                "--no-sandbox",
                "--disable-gpu",
                "--disable-quic",
                "--no-first-run",
                "--disable-background-networking",
                "--disable-component-update",
                "--disable-sync",
                f"--user-data-dir={profile}",
                f"--screenshot={shot}",
                "--window-size=1280,2000",
                page.as_uri(),
            ],
            capture_output=True,
            text=True,
            timeout=180,
        )
    assert shot.is_file(), proc.stderr[-2000:]
    img = cv2.imread(str(shot))
    assert img is not None and img.shape[:2] == (2000, 1280)
    assert float(img.std()) > 20.0, "blank screenshot"
    # the dark-blue header band, the light page background, dark text in the body
    header = img[10:60, 200:1000].reshape(-1, 3).mean(0)  # BGR
    assert header[0] > header[2] + 30 and header.mean() < 120, header
    body = img[200:1200, 60:1220]
    assert (body.mean(-1) > 235).mean() > 0.4
    assert (body.max(-1) < 90).mean() > 0.002, "no text rendered"
    # the summary cards' figures and the contact sheet were drawn (not just an empty page)
    assert len(np.unique(body.reshape(-1, 3) // 16, axis=0)) > 50
