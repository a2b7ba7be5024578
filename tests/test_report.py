"""report: the self-contained HTML page, on the real output of a tiny end-to-end run.

`tiny_case` (conftest.py) runs every stage once per session; tests that need a missing or
broken artefact change a copy of it. Expected figures are read from the stages' own files, so
the page is checked against what the pipeline wrote, not against numbers typed in here.
"""

from __future__ import annotations

import html
import json
import re
import shutil
import subprocess
import tempfile
from pathlib import Path

import cv2
import numpy as np
import pytest
import trimesh
from rich.console import Console

from endopipe.cli import build_pipeline
from endopipe.pipeline.cache import Manifest
from endopipe.pipeline.stage import CaseInfo, StageContext, write_json
from endopipe.stages.metrics.depth import affine_sequence_metrics
from endopipe.stages.report.kit import duration, fmt
from endopipe.stages.report.load import STAGES
from endopipe.stages.report.mesh3d import decimate, page_is_self_contained
from endopipe.stages.report.render import build_report, render_report
from endopipe.stages.report.sections import SECTIONS, per_frame_series
from endopipe.stages.report.stage import Report, ReportConfig

#: A cheaper config for tests that are not about the previews.
FAST = ReportConfig(max_preview_frames=1, mesh_views=1)
PIPELINE = build_pipeline()


def folders_of(case: Path) -> dict[str, Path]:
    """Stage name -> published folder, named by the engine."""
    return {name: PIPELINE.folder(case, name) for name in STAGES}


def read(case: Path, stage: str, name: str) -> dict:
    return json.loads((folders_of(case)[stage] / name).read_text())


@pytest.fixture
def case_copy(tiny_case: Path, tmp_path: Path) -> Path:
    """A copy of the tiny case to break or trim (its ground truth stays where it was)."""
    return Path(shutil.copytree(tiny_case, tmp_path / tiny_case.name))


# --- content ----------------------------------------------------------------------------------


def test_pipeline_report_stage_rendered_every_section(tiny_case: Path) -> None:
    """The report the pipeline itself wrote (07_report): complete, with the GT kind."""
    folder = PIPELINE.folder(tiny_case, "report")
    summary = Manifest.load(folder).summary
    assert all(summary["sections"].values()), summary["sections"]
    assert summary["gt_kind"] == "exact"
    assert summary["mesh_viewer"].startswith("three.js")
    assert [p.name for p in folder.iterdir() if p.name != "manifest.json"] == ["report.html"]


def test_full_report_shows_what_the_stages_wrote(tiny_case: Path) -> None:
    """Every section available: a summary field renamed on the stage's side without the
    report following (or the other way round) fails here, not as a blank cell."""
    page, info = render_report(tiny_case, folders_of(tiny_case), ReportConfig())
    assert list(info.sections) == [key for key, _, _ in SECTIONS]
    assert all(info.sections.values()), info.sections
    assert "Not available" not in page
    assert info.gt_kind == "exact"
    assert info.mesh_viewer.startswith("three.js")
    depth = read(tiny_case, "depth", "metrics.json")
    mesh = read(tiny_case, "mesh", "metrics.json")
    cameras = read(tiny_case, "poses", "cameras.json")
    poses = Manifest.load(folders_of(tiny_case)["poses"]).summary
    registered = sum(f["registered"] for f in cameras["frames"])
    wall = Manifest.load(folders_of(tiny_case)["centerline"]).summary["wall_margin"]
    for label, shown in (
        ("sampled past the prior's wall", f"{1 + wall:.2f}x the wall"),
        ("AbsRel, median scaling", fmt(depth["median_scaled"]["abs_rel"])),
        ("AbsRel, one scale", fmt(depth["sequence_scaled"]["abs_rel"])),
        ("δ1", fmt(depth["median_scaled"]["delta1"])),
        ("SSIM", fmt(depth["heldout_ssim"])),
        ("PSNR", fmt(depth["heldout_psnr"], "dB")),
        ("Chamfer", fmt(mesh["chamfer"], "mm")),
        ("Chamfer % of radius", fmt(mesh["chamfer_pct_radius"], "%")),
        ("F-score", fmt(mesh["fscore"])),
        ("F-score threshold", f"at {mesh['threshold']:.3g} mm"),
        ("ATE", fmt(poses["ate_mm"], "mm")),
        ("registered", f"{registered} of {len(cameras['frames'])} frames"),
        ("protocol", "per-frame median scaling"),
        ("protocol", "one scale for the sequence"),
        ("scale", "metric (mm)"),
        ("video", "data:video/mp4;base64,"),
        ("viewer", "<iframe"),
        ("per-frame plot", "AbsRel per frame."),
        ("distance bands", "nearest camera (radii)"),
    ):
        assert shown in page, (label, shown)
    # one wall-time row per stage, from the manifests
    for stage in STAGES:
        m = Manifest.load(folders_of(tiny_case)[stage])
        assert re.search(rf"<b>{stage}</b>.*?{re.escape(duration(m.wall_s))}", page, re.S), stage
        assert f"{m.peak_rss_mb:,.0f} MB" in page, stage


def test_report_is_self_contained(tiny_case: Path) -> None:
    page = build_report(tiny_case, folders_of(tiny_case))
    assert page_is_self_contained(page)
    # nothing is fetched: every src / href is a data URI or an in-page anchor
    for attr in re.findall(r"""\b(?:src|href)\s*=\s*["']([^"']*)""", page):
        assert attr.startswith(("data:", "#")), attr[:80]
    # the viewer inside the iframe carries three.js itself
    srcdoc = html.unescape(re.search(r'srcdoc="([^"]*)"', page).group(1))
    assert page_is_self_contained(srcdoc)
    assert "WebGLRenderer" in srcdoc and "GLTFLoader" in srcdoc
    assert len(page) < 8 * 2**20


def test_report_degrades_without_gt_and_downstream_stages(case_copy: Path) -> None:
    """A case without ground truth whose run stopped after poses."""
    folders = folders_of(case_copy)
    for stage in ("centerline", "nerf", "depth", "mesh"):
        shutil.rmtree(folders[stage])
    for path in (case_copy / "case.json", folders["ingest"] / "frames.json"):
        write_json(path, {**json.loads(path.read_text()), "gt_dir": None})
    cams = folders["poses"] / "cameras.json"
    write_json(cams, {**json.loads(cams.read_text()), "metric": False, "units": "colmap"})
    page, info = render_report(case_copy, folders, ReportConfig())
    assert info.gt_kind == "none"
    assert info.mesh_viewer == "none"
    assert info.sections["summary"] and info.sections["stages"] and info.sections["poses"]
    assert not info.sections["depth"] and not info.sections["mesh"]
    assert page.count("Not available") >= 3
    assert "No ground truth" in page
    assert "arbitrary" in page  # not metric


def test_a_summary_that_does_not_validate_is_named_not_blanked(case_copy: Path) -> None:
    """05_depth written with another name for a summary field (another endopipe version, or an
    edit): the depth section says so and how to fix it, shows none of the summary's figures, and
    is marked not available; the other sections are untouched."""
    manifest = folders_of(case_copy)["depth"] / "manifest.json"
    written = json.loads(manifest.read_text())
    written["summary"]["unknown_frac"] = written["summary"].pop("unknown_share")
    manifest.write_text(json.dumps(written))
    page, info = render_report(case_copy, folders_of(case_copy), FAST)
    assert not info.sections["depth"]
    assert all(ok for key, ok in info.sections.items() if key != "depth"), info.sections
    depth = visible_text(section_html(page, "depth"))
    assert depth.startswith(  # first thing under the section's title
        "Depth Not available — 05_depth: the depth summary does not match DepthSummary "
        "(unknown_frac: Extra inputs are not permitted)"
    )
    assert depth.count("re-run with --from depth") == 1
    for figure in ("Rendering", "Depth stage render time", "No depth (unknown)"):
        assert figure not in depth, figure
    assert "Depth accuracy" in depth and "Previews" in depth  # what metrics.json and maps give
    assert "re-run with --from" not in visible_text(page.replace(section_html(page, "depth"), ""))


def test_a_lens_refit_is_said_from_its_fields_and_an_old_sentence_is_refused(
    case_copy: Path,
) -> None:
    """The poses summary records a re-fitted lens as fields; the page says it in the one
    sentence `LensRefit.said` makes (the log's too). A manifest from before, with the sentence
    itself, does not validate: the poses section names it instead of showing it."""
    from endopipe.stages.poses.lens import LensRefit

    refit = LensRefit(
        from_model="SIMPLE_RADIAL",
        to_model="OPENCV_FISHEYE",
        omega=1.234,
        focal_px=101.5,
        reprojection_before_px=0.812,
        reprojection_after_px=0.795,
        widest_deg=71.25,
        seconds=1.5,
    )
    manifest = folders_of(case_copy)["poses"] / "manifest.json"
    written = json.loads(manifest.read_text())
    written["summary"]["lens_refit"] = refit.model_dump(mode="json")
    manifest.write_text(json.dumps(written))
    page, info = render_report(case_copy, folders_of(case_copy), FAST)
    poses = visible_text(section_html(page, "poses"))
    assert info.sections["poses"]
    assert f"Lens re-fitted {refit.said}" in poses
    assert "reprojection 0.812 -> 0.795 px, the farthest pixel at 71.2 deg" in refit.said

    written["summary"]["lens_refit"] = f"SIMPLE_RADIAL {refit.said}"
    manifest.write_text(json.dumps(written))
    page, info = render_report(case_copy, folders_of(case_copy), FAST)
    assert not info.sections["poses"]
    assert "re-run with --from poses" in visible_text(section_html(page, "poses"))


def test_report_says_which_metrics_are_missing(case_copy: Path) -> None:
    (folders_of(case_copy)["depth"] / "metrics.json").unlink()
    (folders_of(case_copy)["mesh"] / "metrics.json").unlink()
    cfg = FAST.model_copy(update={"include_mesh_viewer": False})
    page, info = render_report(case_copy, folders_of(case_copy), cfg)
    assert "05_depth/metrics.json is missing" in page
    assert "06_mesh/metrics.json is missing" in page
    assert info.mesh_viewer == "static"
    assert "<iframe" not in page


def test_mesh_not_evaluated_shows_the_reason(case_copy: Path) -> None:
    write_json(
        folders_of(case_copy)["mesh"] / "metrics.json",
        {"evaluated": False, "reason": "no ground-truth mesh"},
    )
    page = build_report(case_copy, folders_of(case_copy), FAST)
    assert "not evaluated: no ground-truth mesh" in page


def test_relative_ground_truth_shows_the_affine_protocol(case_copy: Path) -> None:
    """A relative ground truth (depth up to scale and shift) gets the affine-invariant block."""
    rng = np.random.default_rng(0)
    gt = [rng.uniform(1, 5, (16, 20)).astype(np.float32) for _ in range(3)]
    pred = [2.0 * g + 0.5 + rng.normal(0, 0.05, g.shape).astype(np.float32) for g in gt]
    metrics = affine_sequence_metrics(pred, gt, [None] * 3, [0, 1, 2]) | {"gt_kind": "relative"}
    write_json(folders_of(case_copy)["depth"] / "metrics.json", metrics)
    page, info = render_report(case_copy, folders_of(case_copy), FAST)
    assert info.gt_kind == "relative"
    assert "scale and shift fitted per frame (relative ground truth)" in page
    assert fmt(metrics["affine_invariant"]["spearman"]) in page
    assert "Spearman ρ vs the relative GT" in page


def test_the_fields_depth_against_a_relative_truth_is_scored_up_to_scale_and_shift(
    case_copy: Path,
) -> None:
    """The NeRF section's held-out depth against a relative truth (C3VD's panel): the
    affine-invariant scores alone, no metric protocol the truth cannot support."""
    manifest = folders_of(case_copy)["nerf"] / "manifest.json"
    written = json.loads(manifest.read_text())
    spearman, ssi = 0.9123, 0.1357
    written["summary"]["depth"] = {
        "affine_invariant": {"abs_rel": ssi, "spearman": spearman, "coverage": 0.98}
    }
    manifest.write_text(json.dumps(written))
    page, info = render_report(case_copy, folders_of(case_copy), FAST)
    assert info.sections["nerf"]
    nerf = visible_text(section_html(page, "nerf"))
    assert "Rendered depth on held-out frames" in nerf
    assert fmt(spearman) in nerf and fmt(ssi) in nerf
    assert "median" not in nerf.split("Rendered depth on held-out frames")[1].lower()


def test_broken_artefacts_do_not_break_the_page(case_copy: Path) -> None:
    folders = folders_of(case_copy)
    (folders["mesh"] / "mesh.ply").write_bytes(b"ply\nformat nonsense\n")
    (folders["nerf"] / "manifest.json").write_text("[]")
    first = min(int(p.stem) for p in (folders["depth"] / "depth").glob("*.npy"))
    np.save(folders["depth"] / "depth" / f"{first:06d}.npy", np.zeros((3,), np.float32))
    page, info = render_report(case_copy, folders, FAST)
    assert "mesh.ply unreadable" in page
    assert f"frame {first}: " in page  # that preview row is dropped, with its reason
    assert "Not available" in page
    assert "</html>" in page.rstrip()[-10:]
    assert info.sections["summary"] and info.sections["depth"]


def test_report_stage_writes_one_html_file(tiny_case: Path, tmp_path: Path) -> None:
    out = tmp_path / ".07_report.tmp"
    out.mkdir()
    ctx = StageContext(
        case_dir=tiny_case,
        out=out,
        config=ReportConfig(max_preview_frames=2, mesh_views=1),
        case=CaseInfo.load(tiny_case),
        inputs=folders_of(tiny_case),
        views={name: PIPELINE.by_name[name].View for name in STAGES},
        console=Console(quiet=True),
        quiet=True,
    )
    summary = Report().run(ctx)
    assert [p.name for p in out.iterdir()] == ["report.html"]
    assert summary.gt_kind == "exact" and 0 < summary.size_mb < 8
    assert all(summary.sections.values()), summary.sections
    assert Report.needs == STAGES
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


def test_per_frame_series_reads_the_depth_stage_per_frame_list(tiny_case: Path) -> None:
    per_frame = read(tiny_case, "depth", "metrics.json")["per_frame"]
    series = per_frame_series(per_frame)
    index = [f["index"] for f in per_frame]
    assert series["per-frame median scaling"] == (
        index,
        [f["median_scaled"]["abs_rel"] for f in per_frame],
    )
    assert series["one scale for the sequence"][0] == index
    flat = [{"index": 3, "abs_rel": 0.1}, {"index": 7, "abs_rel": 0.2}]  # relative GT
    assert per_frame_series(flat) == {"per frame": ([3, 7], [0.1, 0.2])}
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
def test_report_renders_in_headless_chromium(tiny_case: Path, tmp_path: Path) -> None:
    page = tmp_path / "report.html"
    page.write_text(build_report(tiny_case, folders_of(tiny_case)), encoding="utf-8")
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


# --- what a user meets ------------------------------------------------------------------------


def section_html(page: str, key: str) -> str:
    """One section of the page, as HTML."""
    return re.search(rf'<section id="{key}">(.*?)</section>', page, re.S).group(1)


def visible_text(fragment: str) -> str:
    """What a reader sees of an HTML fragment: tags, JSON dumps and iframes dropped."""
    fragment = re.sub(r"<(pre|iframe)\b.*?</\1>", " ", fragment, flags=re.S)
    return html.unescape(re.sub(r"\s+", " ", re.sub(r"<[^>]+>", " ", fragment))).strip()


def test_fresh_report_shows_the_run_that_wrote_it(tiny_case: Path) -> None:
    """The report stage runs before its run ends: its page lists that run, in progress, with
    the stages done so far (it used to say "no run records")."""
    page = (PIPELINE.folder(tiny_case, "report") / "report.html").read_text()
    runs = visible_text(section_html(page, "runs"))
    assert "no run records" not in runs
    assert "this run, in progress" in runs
    assert "6 stage(s) done so far" in runs
    assert "ingest, poses, centerline, nerf, depth, mesh" in runs
    record = json.loads(sorted((tiny_case / "runs").glob("*.json"))[-1].read_text())
    assert record["ok"] and record["finished"] and len(record["stages"]) == 7  # then completed


def test_a_run_that_died_is_not_shown_as_running(case_copy: Path) -> None:
    """A record without an end whose process is gone: killed, not "in progress"."""
    proc = subprocess.Popen(["true"])  # a pid that has surely exited
    proc.wait()
    write_json(
        case_copy / "runs" / "20990101T000000_000000.json",
        {"case": "colon", "input": "x", "started": "2099-01-01T00:00:00", "pid": proc.pid},
    )
    page = build_report(case_copy, folders_of(case_copy), FAST)
    runs = visible_text(section_html(page, "runs"))
    assert "no end recorded (killed?)" in runs
    assert "no stage done yet" in runs


def test_loss_legend_sits_beside_the_curves(tiny_case: Path) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from endopipe.stages.nerf.evaluate import loss_figure

    rows = PIPELINE.view(tiny_case, "nerf").train_log()
    fig = loss_figure(rows)
    renderer = FigureCanvasAgg(fig).get_renderer()
    ax = fig.axes[0]
    legend = ax.get_legend().get_window_extent(renderer)
    assert len(ax.get_legend().get_texts()) >= 5
    assert not legend.overlaps(ax.get_window_extent(renderer)), "legend over the curves"
    assert legend.x1 <= fig.bbox.x1  # and still on the figure


def test_heldout_grid_has_column_titles_and_colour_bars() -> None:
    from endopipe.stages.nerf.evaluate import heldout_figure

    img = np.full((32, 40, 3), 0.5, np.float32)
    depth = np.linspace(10, 40, 32 * 40, dtype=np.float32).reshape(32, 40)
    items = [
        (img, {"rgb": img, "depth": depth}, depth * 1.1),
        (img, {"rgb": img, "depth": depth}, None),
    ]
    fig = heldout_figure(items, "mm")
    titles = [ax.get_title() for ax in fig.axes if ax.get_title()]
    assert titles == [
        "held-out image",
        "NeRF rendering",
        "rendered depth (mm)",
        "ground-truth depth (mm)",
    ]
    colour_bars = [ax for ax in fig.axes if ax.get_label() == "<colorbar>"]
    assert len(colour_bars) == 3  # two depth panels, then one (the second frame has no truth)
    assert any(t.get_text() == "no ground truth" for ax in fig.axes for t in ax.texts)


def test_heldout_grid_titles_each_depth_in_its_own_units() -> None:
    """SfM units for the rendered depth, the truth's own for the truth: C3VD's panel is an
    affine proxy of depth, not depth in the poses' units; each then has its own colour scale."""
    from endopipe.stages.nerf.evaluate import heldout_figure

    img = np.full((32, 40, 3), 0.5, np.float32)
    depth = np.linspace(1, 4, 32 * 40, dtype=np.float32).reshape(32, 40)
    items = [(img, {"rgb": img, "depth": depth}, depth * 50 + 20)]
    fig = heldout_figure(items, "colmap", False, "relative")
    titles = [ax.get_title() for ax in fig.axes if ax.get_title()]
    assert titles[2:] == ["rendered depth (colmap)", "ground-truth depth (relative)"]
    ranges = [ax.images[0].get_clim() for ax in fig.axes if ax.images][2:]
    assert ranges[0][1] < 5 < 50 < ranges[1][1], ranges


def _lut(name: str) -> np.ndarray:
    cmap = {"turbo": cv2.COLORMAP_TURBO, "inferno": cv2.COLORMAP_INFERNO}[name]
    return cv2.applyColorMap(np.arange(256, dtype=np.uint8)[:, None], cmap)[:, 0, ::-1]


def _lut_distance(pixels: np.ndarray, lut: np.ndarray) -> float:
    """Median distance of RGB pixels to the nearest colour of a colour map."""
    d = np.linalg.norm(pixels[:, None, :].astype(float) - lut[None].astype(float), axis=-1)
    return float(np.median(d.min(1)))


def check_preview_frame(frame: np.ndarray, h: int, w: int) -> None:
    """A preview.mp4 frame (h x w maps): three panels, each titled; depth in turbo and the
    error in inferno, as in the report; a colour bar in the same map under each."""
    assert frame.shape[0] >= h + 28 and frame.shape[1] in (3 * w, 3 * w + 1), frame.shape
    for col in range(3):  # a title above every panel
        assert (frame[:14, col * w : (col + 1) * w].max(-1) > 180).sum() > 20, col
    mid = frame.shape[0] // 2
    error = frame[mid - 20 : mid + 20, 2 * w + 4 : 3 * w - 4].reshape(-1, 3)
    error = error[error.max(-1) > 40]  # evaluated pixels (black: none)
    assert _lut_distance(error, _lut("inferno")) < 12 < _lut_distance(error, _lut("turbo"))
    for col, cmap in ((1, "turbo"), (2, "inferno")):  # a colour bar under depth and error
        bottom = frame[h + 14 :, col * w + 8 : (col + 1) * w - 8].reshape(-1, 3).astype(int)
        bar = bottom[bottom.max(-1) - bottom.min(-1) > 60]  # coloured: not text, not background
        other = "inferno" if cmap == "turbo" else "turbo"
        assert len(bar) > w // 2, cmap
        near, far = _lut_distance(bar, _lut(cmap)), _lut_distance(bar, _lut(other))
        assert near < 30 and 2 * near < far, (cmap, near, far)  # H.264 blurs a thin bar


def test_preview_video_panels_are_titled_with_colour_bars_in_the_report_maps(
    tiny_case: Path,
) -> None:
    import av

    depth = PIPELINE.view(tiny_case, "depth")
    h, w = depth.depth(depth.indices[0]).shape
    with av.open(str(depth.preview_path)) as video:
        check_preview_frame(next(video.decode(video=0)).to_ndarray(format="rgb24"), h, w)


def test_mesh_section_is_one_readable_table(tiny_case: Path) -> None:
    page = build_report(tiny_case, folders_of(tiny_case), FAST)
    mesh = section_html(page, "mesh")
    shown = visible_text(mesh)
    metrics = read(tiny_case, "mesh", "metrics.json")
    for raw_key in (
        "gt_area_seen",
        "eval_s",
        "components_removed",
        "chamfer_pct_radius",
        "[chamfer]",
        "build s",
    ):
        assert raw_key not in shown, raw_key
    assert mesh.count('class="grid metrics grouped"') == 1
    assert shown.count("Chamfer distance") == 1
    assert f"Clean-up {metrics['components_removed']:,} small components removed" in shown
    vertices = len(trimesh.load(folders_of(tiny_case)["mesh"] / "mesh.ply").vertices)
    assert metrics["vertices"] == vertices
    assert f"Vertices {vertices:,} in mesh.ply, after clean-up" in shown
    assert f"before clean-up {metrics['raw_vertices']:,} vertices" in shown
    assert f"Truth surface compared {fmt(metrics['gt_area_seen'])[:4]}" in shown
    assert "mm²" in shown and "Evaluation time" in shown


def test_mesh_log_and_report_give_the_same_vertex_count(tiny_case: Path, tmp_path: Path) -> None:
    """The log used to print the count before clean-up, the report the one after."""
    from endopipe.stages.mesh.stage import Mesh, MeshConfig

    out = tmp_path / ".06_mesh.tmp"
    out.mkdir()
    console = Console(record=True, width=200)
    ctx = StageContext(
        case_dir=tiny_case,
        out=out,
        config=MeshConfig(evaluate=False),
        case=CaseInfo.load(tiny_case),
        inputs={n: folders_of(tiny_case)[n] for n in Mesh.needs},
        views={n: PIPELINE.by_name[n].View for n in Mesh.needs},
        console=console,
        quiet=False,
    )
    Mesh().run(ctx)
    log = console.export_text()
    vertices = len(trimesh.load(out / "mesh.ply").vertices)
    assert f"mesh.ply: {vertices:,} vertices" in log, log
    assert "before clean-up" in log
    raw = json.loads((out / "metrics.json").read_text())["raw_vertices"]
    assert f"{raw:,} vertices" in log and raw >= vertices


def test_render_times_say_what_they_time(tiny_case: Path) -> None:
    page = visible_text(build_report(tiny_case, folders_of(tiny_case), FAST))
    nerf = read(tiny_case, "nerf", "metrics.json")
    depth = Manifest.load(folders_of(tiny_case)["depth"]).summary
    assert "Render time per frame" not in page
    expected = (
        f"Field render time, colour and depth {visible_text(fmt(nerf['render_rgb_ms'], 'ms'))}",
        f"Depth stage render time {visible_text(fmt(depth['ms_per_frame'], 'ms'))} per frame",
    )
    for text_ in expected:
        assert text_ in page, text_
