"""report: one self-contained HTML page per case (07_report/report.html).

Everything is inlined, so the page opens offline and can be mailed as one file: images are base64
PNG / JPEG data URIs, the CSS is inline, the depth preview video (when small enough) is an mp4
data URI, and the 3D mesh viewer is trimesh's three.js page (trimesh bundles three.js inside
its package, no CDN) placed in an `<iframe srcdoc>`. Static renderings of the mesh are
always included as well, for print and for browsers without WebGL.

What the page shows: the case (input, frames, registered ratio, metric or not, ground-truth
kind), every stage's wall time and peak memory (from each stage folder's manifest.json), the
camera trajectory and the centre line, the NeRF's loss curves, depth previews with error maps,
the metric tables (depth under both protocols, mesh, poses, PSNR / SSIM) and the recent runs.
Any missing artefact (no ground truth, no mesh metrics, a stage folder absent) is shown as
"not available" with the reason; a section never takes the page down.

The rendering is pure functions over folders: `build_report(case_dir, stage_folders)` returns
the HTML, so it is testable on hand-built folders without running the pipeline.
"""

from __future__ import annotations

import base64
import csv
import datetime as dt
import html
import io
import json
import math
import platform
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from pydantic import Field

from endopipe.pipeline.cache import Manifest
from endopipe.pipeline.stage import CaseInfo, Stage, StageConfig, StageContext, Summary

#: The stages whose folders the report reads, in DAG order.
STAGES = ("ingest", "poses", "centerline", "nerf", "depth", "mesh")

#: Depth metrics in display order: (key, label, higher is better).
DEPTH_METRICS = (
    ("abs_rel", "AbsRel", False),
    ("sq_rel", "SqRel", False),
    ("rmse", "RMSE", False),
    ("rmse_log", "RMSE log", False),
    ("delta1", "δ < 1.25", True),
    ("delta2", "δ < 1.25²", True),
    ("delta3", "δ < 1.25³", True),
    ("spearman", "Spearman ρ", True),
)
#: Protocol keys of a depth metrics block (`sequence_scaled` and `global_scaled` are one thing).
DEPTH_PROTOCOLS = (
    ("median_scaled", "per-frame median scaling"),
    ("sequence_scaled", "one scale for the sequence"),
    ("global_scaled", "one scale for the sequence"),
    ("affine_invariant", "scale and shift fitted per frame (relative ground truth)"),
)
TISSUE_RGB = (214, 146, 138)
NEAREST = {"interpolation": "nearest", "interpolation_stage": "rgba"}


class ReportConfig(StageConfig):
    title: str | None = Field(
        None, description="Page title; default 'endopipe report: <case name>'."
    )
    max_preview_frames: int = Field(
        4,
        ge=0,
        le=16,
        description="Frames in the depth preview (RGB | depth | GT depth | abs-rel error), "
        "evenly spaced over the sequence.",
    )
    preview_width: int = Field(
        320, ge=64, le=1024, description="Width in pixels of a preview tile (downscale only)."
    )
    error_max: float = Field(
        0.25, gt=0, description="Abs-rel error at the top of the error maps' colour scale."
    )
    include_video: bool = Field(
        True, description="Inline 05_depth/preview.mp4 when it is at most max_video_mb."
    )
    max_video_mb: float = Field(4.0, ge=0, description="Largest preview video inlined (MB).")
    include_mesh_viewer: bool = Field(
        True,
        description="Interactive 3D viewer of the mesh: trimesh's three.js page, which carries "
        "three.js inside it (no network), in an iframe. Static views are always included.",
    )
    mesh_max_faces: int = Field(
        20_000,
        ge=100,
        description="Decimate the mesh to at most this many faces for the viewer and the "
        "static views (keeps the page a few MB).",
    )
    mesh_views: int = Field(
        3, ge=0, le=3, description="Static renderings of the mesh: side, top, end-on."
    )
    jpeg_quality: int = Field(88, ge=30, le=100, description="JPEG quality of photo-like images.")
    max_runs: int = Field(5, ge=0, description="Most recent runs listed from <case>/runs/.")


class ReportSummary(Summary):
    size_mb: float
    gt_kind: str
    mesh_viewer: str
    sections: dict[str, bool]


class Report(Stage):
    """A self-contained HTML report: summary, timings, plots, depth previews, metrics, 3D mesh."""

    name = "report"
    needs = ("ingest", "poses", "centerline", "nerf", "depth", "mesh")
    version = 1
    Config = ReportConfig

    def run(self, ctx: StageContext) -> ReportSummary:
        cfg: ReportConfig = ctx.config  # type: ignore[assignment]
        folders = {name: ctx.input_dir(name) for name in self.needs}
        page, info = render_report(ctx.case_dir, folders, cfg)
        path = ctx.out / "report.html"
        path.write_text(page, encoding="utf-8")
        size_mb = path.stat().st_size / 2**20
        missing = [k for k, ok in info.sections.items() if not ok]
        ctx.log(
            f"report.html: {size_mb:.1f} MB, mesh viewer: {info.mesh_viewer}"
            + (f"; not available: {', '.join(missing)}" if missing else "")
        )
        return ReportSummary(
            size_mb=round(size_mb, 3),
            gt_kind=info.gt_kind,
            mesh_viewer=info.mesh_viewer,
            sections=info.sections,
        )


# =============================================================================================
# Inputs: everything read defensively (a missing or malformed file gives None, not an error)
# =============================================================================================


@dataclass
class ReportInfo:
    """What the page ended up holding (the stage's summary)."""

    gt_kind: str = "none"
    mesh_viewer: str = "none"
    sections: dict[str, bool] = field(default_factory=dict)


@dataclass
class CaseData:
    """The artefacts of one case, loaded once."""

    case_dir: Path
    folders: dict[str, Path]
    cfg: ReportConfig
    case: CaseInfo | None = None
    manifests: dict[str, Manifest | None] = field(default_factory=dict)
    frames: dict | None = None  # 01_ingest/frames.json
    cameras: dict | None = None  # 02_poses/cameras.json
    centerline: dict | None = None  # 03_centerline/centerline.json
    nerf_metrics: dict | None = None
    depth_metrics: dict | None = None
    mesh_metrics: dict | None = None
    _gt: Any = None
    _gt_error: str | None = None

    @property
    def units(self) -> str:
        if self.cameras is None:
            return ""
        return "mm" if self.cameras.get("metric") else str(self.cameras.get("units", "units"))

    def folder(self, stage: str) -> Path | None:
        path = self.folders.get(stage)
        return path if path is not None and path.is_dir() else None

    def file(self, stage: str, rel: str) -> Path | None:
        folder = self.folder(stage)
        if folder is None:
            return None
        path = folder / rel
        return path if path.is_file() else None

    def summary(self, stage: str) -> dict:
        m = self.manifests.get(stage)
        return dict(m.summary) if m is not None else {}

    def gt_dir(self) -> Path | None:
        raw = (self.frames or {}).get("gt_dir") or (self.case.gt_dir if self.case else None)
        return Path(raw) if raw else None

    def ground_truth(self) -> Any:
        """The case's GroundTruthSource, or None (reason in `_gt_error`)."""
        if self._gt is not None or self._gt_error is not None:
            return self._gt
        gt_dir = self.gt_dir()
        if gt_dir is None:
            self._gt_error = "the case has no ground truth"
            return None
        try:
            from endopipe.stages.io.ground_truth import open_ground_truth

            self._gt = open_ground_truth(gt_dir)
        except Exception as e:  # noqa: BLE001 - any reader failure: report without GT
            self._gt_error = f"ground truth at {gt_dir} could not be read ({_one_line(e)})"
        return self._gt

    def gt_kind(self) -> str:
        """exact | pseudo | none: from the evaluations first, then from the GT reader."""
        for data in (self.depth_metrics, self.mesh_metrics, self.nerf_metrics):
            if isinstance(data, dict) and data.get("gt_kind"):
                return str(data["gt_kind"])
        for stage in ("depth", "mesh", "poses"):
            kind = self.summary(stage).get("gt_kind")
            if kind:
                return str(kind)
        gt = self.ground_truth()
        return str(getattr(gt, "kind", "exact")) if gt is not None else "none"

    def frame_entry(self, index: int) -> dict | None:
        for f in (self.frames or {}).get("frames", []):
            if f.get("index") == index:
                return f
        return None


def load_case(case_dir: Path, folders: dict[str, Path], cfg: ReportConfig) -> CaseData:
    data = CaseData(case_dir=Path(case_dir), folders=dict(folders), cfg=cfg)
    try:
        data.case = CaseInfo.load(data.case_dir)
    except Exception:  # noqa: BLE001 - a hand-built folder may have no case.json
        data.case = None
    for stage in STAGES:
        folder = data.folder(stage)
        data.manifests[stage] = Manifest.load(folder) if folder is not None else None
    data.frames = _read_json(data.file("ingest", "frames.json"))
    data.cameras = _read_json(data.file("poses", "cameras.json"))
    data.centerline = _read_json(data.file("centerline", "centerline.json"))
    data.nerf_metrics = _read_json(data.file("nerf", "metrics.json"))
    data.depth_metrics = _read_json(data.file("depth", "metrics.json"))
    data.mesh_metrics = _read_json(data.file("mesh", "metrics.json"))
    return data


def _read_json(path: Path | None) -> dict | None:
    if path is None:
        return None
    try:
        value = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return value if isinstance(value, dict) else None


def _one_line(e: BaseException) -> str:
    text = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
    return text[:200]


# =============================================================================================
# The page
# =============================================================================================


def build_report(
    case_dir: Path, stage_folders: dict[str, Path], config: ReportConfig | None = None
) -> str:
    """The report's HTML for a case whose stage folders are `stage_folders` (name -> folder)."""
    return render_report(case_dir, stage_folders, config or ReportConfig())[0]


def render_report(
    case_dir: Path, stage_folders: dict[str, Path], cfg: ReportConfig
) -> tuple[str, ReportInfo]:
    data = load_case(case_dir, stage_folders, cfg)
    info = ReportInfo(gt_kind=_safe_value(data.gt_kind, "none"))
    sections: list[tuple[str, str, Callable[[CaseData, ReportInfo], str | None]]] = [
        ("summary", "Summary", section_summary),
        ("stages", "Stages: time and memory", section_stages),
        ("input", "Input frames", section_input),
        ("poses", "Camera trajectory and centre line", section_poses),
        ("nerf", "NeRF training", section_nerf),
        ("depth", "Depth", section_depth),
        ("mesh", "Mesh", section_mesh),
        ("runs", "Runs and environment", section_runs),
    ]
    body = []
    for key, title, fn in sections:
        try:
            content = fn(data, info)
        except Exception as e:  # noqa: BLE001 - a broken artefact must not take the page down
            info.sections[key] = False
            content = not_available(f"this section failed to render: {_one_line(e)}")
        else:
            info.sections.setdefault(key, content is not None)
            if content is None:
                content = not_available("no artefacts for this section")
        body.append(f'<section id="{key}"><h2>{html.escape(title)}</h2>\n{content}\n</section>')
    name = data.case.name if data.case else data.case_dir.name
    title = cfg.title or f"endopipe report: {name}"
    nav = "".join(f'<a href="#{k}">{html.escape(t.split(":")[0])}</a>' for k, t, _ in sections)
    generated = dt.datetime.now().strftime("%Y-%m-%d %H:%M")
    page = PAGE.format(
        title=html.escape(title),
        css=CSS,
        subtitle=html.escape(data.case.input if data.case else str(data.case_dir)),
        generated=html.escape(generated),
        version=html.escape(_endopipe_version()),
        nav=nav,
        body="\n".join(body),
    )
    return page, info


def _safe_value(fn: Callable[[], str], default: str) -> str:
    try:
        return fn()
    except Exception:  # noqa: BLE001
        return default


def _endopipe_version() -> str:
    try:
        import importlib.metadata

        return importlib.metadata.version("endopipe")
    except Exception:  # noqa: BLE001
        return "dev"


# --- small HTML helpers ----------------------------------------------------------------------


def not_available(reason: str) -> str:
    return f'<div class="na"><b>Not available</b> &mdash; {html.escape(reason)}</div>'


def fmt(value: Any, unit: str = "") -> str:
    """A number for a table: 4 significant digits, thousands separators, '—' for missing."""
    if value is None or value == "":
        return '<span class="muted">&mdash;</span>'
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int):
        text = f"{value:,}"
    elif isinstance(value, float):
        if not math.isfinite(value):
            return '<span class="muted">&mdash;</span>'
        if value != 0 and abs(value) < 1e-4:
            text = f"{value:.2g}"
        elif abs(value) >= 1000:
            text = f"{value:,.0f}"
        elif abs(value) >= 100:
            text = f"{value:.1f}"
        else:
            text = f"{value:.4g}"
    else:
        return html.escape(str(value))
    return text + (f'<span class="unit"> {html.escape(unit)}</span>' if unit else "")


def kv_table(rows: list[tuple[str, str]], cls: str = "kv") -> str:
    body = "".join(f"<tr><th>{html.escape(k)}</th><td>{v}</td></tr>" for k, v in rows)
    return f'<table class="{cls}">{body}</table>'


def figure_html(uri: str, caption: str, cls: str = "") -> str:
    return (
        f'<figure class="{cls}"><img src="{uri}" alt="{html.escape(caption)}">'
        f"<figcaption>{html.escape(caption)}</figcaption></figure>"
    )


def badge(text: str, kind: str) -> str:
    return f'<span class="badge {kind}">{html.escape(text)}</span>'


def details_json(summary: str, data: Any) -> str:
    text = json.dumps(data, indent=2, default=str)
    return (
        f"<details><summary>{html.escape(summary)}</summary>"
        f"<pre>{html.escape(text)}</pre></details>"
    )


# --- images ------------------------------------------------------------------------------------


def image_uri(rgb: np.ndarray, fmt_: str = "png", quality: int = 88) -> str:
    """An RGB(A) or grey uint8 image as a data URI."""
    img = np.asarray(rgb)
    if img.ndim == 3 and img.shape[2] == 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
    elif img.ndim == 3 and img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_RGBA2BGRA)
    if fmt_ == "jpg":
        if img.ndim == 3 and img.shape[2] == 4:
            img = img[:, :, :3]
        ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, quality])
        mime = "image/jpeg"
    else:
        ok, buf = cv2.imencode(".png", img, [cv2.IMWRITE_PNG_COMPRESSION, 9])
        mime = "image/png"
    if not ok:
        raise ValueError("image encoding failed")
    return f"data:{mime};base64,{base64.b64encode(buf.tobytes()).decode()}"


def file_image_uri(
    path: Path, max_width: int = 1100, fmt_: str = "png", quality: int = 88
) -> str | None:
    """An image file, downscaled to max_width, as a data URI; None when unreadable."""
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        return None
    if img.dtype != np.uint8:
        img = cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    if img.shape[1] > max_width:
        h = round(img.shape[0] * max_width / img.shape[1])
        img = cv2.resize(img, (max_width, h), interpolation=cv2.INTER_AREA)
    if img.ndim == 3 and img.shape[2] == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    elif img.ndim == 3 and img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2RGBA)
    return image_uri(img, fmt_, quality)


def _figure(width: float, height: float):
    from matplotlib.figure import Figure  # no pyplot: no global state, no GUI backend

    fig = Figure(figsize=(width, height), dpi=100)
    return fig


def figure_uri(fig, fmt_: str = "png", quality: int = 88) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=fig.dpi, facecolor="white")  # laid out by tight_layout
    if fmt_ == "png":
        return f"data:image/png;base64,{base64.b64encode(buf.getvalue()).decode()}"
    img = cv2.imdecode(np.frombuffer(buf.getvalue(), np.uint8), cv2.IMREAD_COLOR)
    return image_uri(cv2.cvtColor(img, cv2.COLOR_BGR2RGB), "jpg", quality)


# =============================================================================================
# Sections. Each returns HTML, or None when it has nothing at all to show.
# =============================================================================================


def section_summary(data: CaseData, info: ReportInfo) -> str:
    ing, pos = data.summary("ingest"), data.summary("poses")
    frames = data.frames or {}
    n_frames = len(frames.get("frames", [])) or ing.get("kept")
    cams = data.cameras
    registered = total = None
    if cams is not None:
        total = len(cams.get("frames", []))
        registered = sum(1 for f in cams.get("frames", []) if f.get("registered"))
    elif pos:
        registered, total = pos.get("registered"), pos.get("total")
    metric = cams.get("metric") if cams is not None else pos.get("metric")
    gt = info.gt_kind
    gt_badge = {
        "exact": badge("exact", "ok"),
        "pseudo": badge("pseudo", "warn"),
        "none": badge("none", "muted"),
    }.get(gt, badge(gt, "muted"))

    cards = []

    def card(label: str, value: str, note: str = "") -> None:
        cards.append(
            f'<div class="card"><div class="label">{html.escape(label)}</div>'
            f'<div class="value">{value}</div><div class="note">{note}</div></div>'
        )

    src_frames = ing.get("source_frames")
    card(
        "Frames",
        fmt(n_frames) if n_frames else fmt(None),
        f"of {src_frames:,} in the input" if isinstance(src_frames, int) else "",
    )
    if registered is not None and total:
        card("Registered", f"{100 * registered / total:.0f}%", f"{registered} of {total} frames")
    else:
        card("Registered", fmt(None), "no poses")
    if metric is None:
        card("Scale", fmt(None), "no poses")
    else:
        card(
            "Scale",
            "metric (mm)" if metric else "arbitrary",
            "aligned to ground truth"
            if pos.get("aligned_to_gt")
            else ("" if metric else "monocular: up to scale"),
        )
    card(
        "Ground truth",
        gt_badge,
        {"pseudo": "e.g. stereo-derived", "relative": "depth up to scale and shift"}.get(gt, ""),
    )
    dm = (data.depth_metrics or {}).get("median_scaled") or {}
    am = (data.depth_metrics or {}).get("affine_invariant") or {}
    if isinstance(dm, dict) and dm.get("abs_rel") is not None:
        card("Depth AbsRel", fmt(dm.get("abs_rel")), "per-frame median scaling")
    elif isinstance(am, dict) and am.get("abs_rel") is not None:
        card("Depth AbsRel", fmt(am.get("abs_rel")), "scale and shift fitted (relative GT)")
        card("Depth rank corr.", fmt(am.get("spearman")), "Spearman ρ vs the relative GT")
    mm = _flat_numbers(data.mesh_metrics or {})
    mm = {k: v for k, v in mm.items() if "pct" not in k and "median" not in k}
    chamfer = _first(mm, ("chamfer",))
    fscore = _first(mm, ("fscore", "f_score", "f-score"))
    if chamfer is not None:
        card("Chamfer", fmt(chamfer[1], "mm"), "mean of both directions")
    if fscore is not None:
        tau = _first(mm, ("threshold", "tau"))
        note = f"at {tau[1]:.3g} mm" if tau is not None else fscore[0]
        card("F-score", fmt(fscore[1]), html.escape(note))
    if pos.get("ate_mm") is not None:
        from_gt = pos.get("source") == "gt"
        note = "poses are the ground truth" if from_gt else "after sim(3) alignment"
        card("ATE", fmt(pos.get("ate_mm"), "mm"), note)
    psnr = image_metric(data, "psnr")
    if psnr is not None:
        card("PSNR", fmt(psnr, "dB"), "held-out frames")

    case = data.case
    rows = [
        ("Case", html.escape(case.name if case else data.case_dir.name)),
        ("Input", f"<code>{html.escape(case.input)}</code>" if case else fmt(None)),
        ("Input kind", html.escape(case.kind) if case else fmt(None)),
    ]
    if frames:
        rows.append(("Working resolution", f"{frames.get('width')} × {frames.get('height')} px"))
    if ing.get("dropped"):
        dropped = ", ".join(f"{v} {k.replace('_', ' ')}" for k, v in ing["dropped"].items() if v)
        rows.append(("Frames dropped", html.escape(dropped or "none")))
    if cams is not None:
        rows.append(
            (
                "Camera",
                html.escape(
                    f"{cams.get('model', '?')} {cams.get('width')}×{cams.get('height')}, "
                    f"fx {cams.get('fx', 0):.1f}, fy {cams.get('fy', 0):.1f}, "
                    f"cx {cams.get('cx', 0):.1f}, cy {cams.get('cy', 0):.1f} px"
                ),
            )
        )
        rows.append(("Pose source", html.escape(str(cams.get("source", "?")))))
        rows.append(("Units", html.escape(data.units)))
    gt_dir = data.gt_dir()
    gt_note = html.escape(str(gt_dir)) if gt_dir else "none"
    if gt != "none":
        ds = getattr(data.ground_truth(), "dataset", "")
        gt_note = f"{gt_badge} {html.escape(ds)} <code>{gt_note}</code>"
    rows.append(("Ground truth", gt_note))
    honesty = (
        '<p class="note">Ground truth is <b>pseudo</b> (not measured): treat metrics as '
        "agreement with another estimate, not as accuracy.</p>"
        if gt == "pseudo"
        else (
            '<p class="note">No ground truth: the page shows estimates and internal '
            "consistency only; no accuracy is claimed.</p>"
            if gt == "none"
            else ""
        )
    )
    return f'<div class="cards">{"".join(cards)}</div>{honesty}{kv_table(rows)}'


def section_stages(data: CaseData, info: ReportInfo) -> str | None:
    rows = []
    walls = [m.wall_s for m in data.manifests.values() if m is not None]
    if not walls and not any(data.folder(s) for s in STAGES):
        return None
    longest = max(walls) if walls else 1.0
    for stage in STAGES:
        m = data.manifests.get(stage)
        folder = data.folder(stage)
        name = folder.name if folder is not None else "&mdash;"
        if m is None:
            state = badge("no manifest" if folder is not None else "missing", "bad")
            rows.append(
                f"<tr><td><b>{stage}</b></td><td><code>{name}</code></td><td>{state}</td>"
                "<td colspan=5 class=muted>not available</td></tr>"
            )
            continue
        share = 100.0 * m.wall_s / longest if longest > 0 else 0.0
        finished = dt.datetime.fromtimestamp(m.finished).strftime("%Y-%m-%d %H:%M:%S")
        size = sum(f.size for f in m.files.values()) / 2**20
        rows.append(
            f"<tr><td><b>{stage}</b></td><td><code>{html.escape(name)}</code></td>"
            f"<td>{badge('done', 'ok')}</td>"
            f'<td class="num">{_duration(m.wall_s)}'
            f'<div class="bar"><span style="width:{share:.1f}%"></span></div></td>'
            f'<td class="num">{m.peak_rss_mb:,.0f} MB</td>'
            f'<td class="num">{len(m.files)} files, {size:,.1f} MB</td>'
            f"<td>v{m.version} <code>{m.key[:8]}</code></td><td>{finished}</td></tr>"
        )
    total_wall = sum(walls)
    peak = max((m.peak_rss_mb for m in data.manifests.values() if m is not None), default=0.0)
    table = (
        '<table class="grid"><thead><tr><th>stage</th><th>folder</th><th>state</th>'
        "<th>wall time</th><th>peak memory</th><th>outputs</th><th>version, key</th>"
        "<th>finished</th></tr></thead><tbody>"
        + "".join(rows)
        + f'</tbody><tfoot><tr><th colspan=3>total</th><td class="num">{_duration(total_wall)}'
        f'</td><td class="num">{peak:,.0f} MB (max)</td><td colspan=3></td></tr></tfoot></table>'
    )
    configs = "".join(
        details_json(f"{stage}: config and summary", {"config": m.config, "summary": m.summary})
        for stage in STAGES
        if (m := data.manifests.get(stage)) is not None
    )
    note = (
        '<p class="note">Wall time and peak resident memory of the process while the stage ran, '
        "from each stage folder's manifest.json; a cached stage shows the run that made it.</p>"
    )
    return table + note + configs


def _duration(seconds: float) -> str:
    if seconds < 60:
        return f"{seconds:.1f} s"
    if seconds < 3600:
        return f"{int(seconds // 60)} min {seconds % 60:.0f} s"
    return f"{int(seconds // 3600)} h {int(seconds % 3600 // 60)} min"


def section_input(data: CaseData, info: ReportInfo) -> str | None:
    path = data.file("ingest", "contact_sheet.png")
    ing = data.summary("ingest")
    parts = []
    if path is not None:
        uri = file_image_uri(path, 1100, "jpg", data.cfg.jpeg_quality)
        if uri:
            parts.append(
                figure_html(
                    uri,
                    "Contact sheet: selected frames; outside the field of view dimmed, "
                    "specular highlights in magenta (masked out).",
                    "medium",
                )
            )
    if ing:
        rows = [
            ("Kept frames", fmt(ing.get("kept"))),
            ("Field of view", html.escape(str(ing.get("fov_shape", "—")))),
            ("Field-of-view fraction", fmt(ing.get("fov_fraction"))),
            ("Mean specular fraction", fmt(ing.get("mean_specular_fraction"))),
        ]
        parts.append(kv_table(rows))
    if not parts:
        return None
    return "".join(parts)


# --- poses and centre line ----------------------------------------------------------------------


def camera_arrays(cameras: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Registered frames' indices, centres (N, 3) and viewing directions (N, 3)."""
    ids, centres, views = [], [], []
    for f in cameras.get("frames", []):
        if f.get("registered") and f.get("c2w") is not None:
            c2w = np.asarray(f["c2w"], dtype=np.float64)
            ids.append(int(f["index"]))
            centres.append(c2w[:3, 3])
            views.append(c2w[:3, 2])
    return np.asarray(ids), np.reshape(centres, (-1, 3)), np.reshape(views, (-1, 3))


def gt_centres(data: CaseData, ids: np.ndarray) -> np.ndarray | None:
    """Ground-truth camera centres for the registered frames, when poses are in the GT frame."""
    if not (data.cameras or {}).get("metric"):
        return None
    gt = data.ground_truth()
    if gt is None or not gt.has_poses():
        return None
    poses = gt.poses()
    out = []
    for i in ids:
        entry = data.frame_entry(int(i))
        src = entry.get("source_index", int(i)) if entry else int(i)
        if src >= len(poses):
            return None
        out.append(np.asarray(poses[src])[:3, 3])
    return np.reshape(out, (-1, 3))


def plot_trajectory(
    centres: np.ndarray,
    views: np.ndarray,
    centerline: dict | None,
    gt: np.ndarray | None,
    units: str,
) -> str:
    """Three panels: 3D view, the plane of the path's two main axes, radius along the curve."""
    fig = _figure(13.0, 4.2)
    ax3 = fig.add_subplot(1, 3, 1, projection="3d")
    ax2 = fig.add_subplot(1, 3, 2)
    ax_r = fig.add_subplot(1, 3, 3)
    pts = [centres]
    curve = radius = arclen = None
    if centerline is not None and centerline.get("points"):
        curve = np.asarray(centerline["points"], dtype=np.float64).reshape(-1, 3)
        radius = np.asarray(centerline.get("radius", []), dtype=np.float64)
        arclen = np.asarray(centerline.get("arclength", []), dtype=np.float64)
        pts.append(curve)
    if gt is not None:
        pts.append(gt)
    allp = np.concatenate(pts)
    mean = allp.mean(0)
    _, _, vt = np.linalg.svd(allp - mean, full_matrices=False)
    if vt.shape[0] < 3:
        vt = np.eye(3)
    scale = float(np.ptp(allp, axis=0).max()) or 1.0
    colours = np.linspace(0, 1, len(centres))

    if gt is not None:
        ax3.plot(*gt.T, color="0.55", lw=1.2, ls="--", label="ground truth")
    if curve is not None:
        ax3.plot(*curve.T, color="#c0392b", lw=2.0, label="centre line")
    ax3.plot(*centres.T, color="#1f4e79", lw=1.0, alpha=0.6)
    ax3.scatter(*centres.T, c=colours, cmap="viridis", s=10, depthshade=False, label="cameras")
    step = max(1, len(centres) // 12)
    q = centres[::step]
    d = views[::step] * 0.06 * scale
    ax3.quiver(*q.T, *d.T, color="#2c3e50", lw=0.8, arrow_length_ratio=0.25)
    mid = (allp.max(0) + allp.min(0)) / 2
    half = 0.55 * scale
    ax3.set_xlim(mid[0] - half, mid[0] + half)
    ax3.set_ylim(mid[1] - half, mid[1] + half)
    ax3.set_zlim(mid[2] - half, mid[2] + half)
    ax3.set_box_aspect((1, 1, 1))
    ax3.set_xlabel(f"x ({units})", fontsize=8)
    ax3.set_ylabel(f"y ({units})", fontsize=8)
    ax3.set_zlabel(f"z ({units})", fontsize=8)
    ax3.tick_params(labelsize=7)
    ax3.legend(fontsize=7, loc="upper left")
    ax3.set_title("3D trajectory", fontsize=10)

    def plane(p: np.ndarray) -> np.ndarray:
        return (p - mean) @ vt[:2].T

    if gt is not None:
        g2 = plane(gt)
        ax2.plot(g2[:, 0], g2[:, 1], color="0.55", ls="--", lw=1.2, label="ground truth")
    if curve is not None:
        c2 = plane(curve)
        ax2.plot(c2[:, 0], c2[:, 1], color="#c0392b", lw=2.0, label="centre line")
        if radius is not None and len(radius) == len(curve) and len(curve) > 2:
            t = np.gradient(c2, axis=0)
            n = np.stack([-t[:, 1], t[:, 0]], 1)
            n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
            for sgn in (1, -1):
                w = c2 + sgn * radius[:, None] * n
                ax2.plot(w[:, 0], w[:, 1], color="#c0392b", lw=0.8, alpha=0.5)
            ax2.plot([], [], color="#c0392b", lw=0.8, alpha=0.5, label="centre line ± radius")
    p2 = plane(centres)
    ax2.plot(p2[:, 0], p2[:, 1], color="#1f4e79", lw=1.0, alpha=0.6)
    sc = ax2.scatter(p2[:, 0], p2[:, 1], c=colours, cmap="viridis", s=12, zorder=3, label="cameras")
    ax2.set_aspect("equal", adjustable="datalim")
    ax2.set_xlabel(f"main axis ({units})", fontsize=8)
    ax2.set_ylabel(f"second axis ({units})", fontsize=8)
    ax2.tick_params(labelsize=7)
    ax2.legend(fontsize=7, loc="best")
    ax2.set_title("Plane of the path (principal axes)", fontsize=10)
    cb = fig.colorbar(sc, ax=ax2, fraction=0.046, pad=0.02)
    cb.set_label("frame order", fontsize=7)
    cb.set_ticks([])

    if radius is not None and len(radius) and arclen is not None and len(arclen) == len(radius):
        ax_r.plot(arclen, radius, color="#c0392b", lw=1.5)
        span = centerline.get("camera_span") if centerline else None
        if span and len(span) == 2:
            ax_r.axvspan(span[0], span[1], color="#1f4e79", alpha=0.08, label="camera span")
            ax_r.legend(fontsize=7)
        ax_r.set_xlabel(f"arc length ({units})", fontsize=8)
        ax_r.set_ylabel(f"radius ({units})", fontsize=8)
        ax_r.set_ylim(bottom=0)
        ax_r.set_title("Lumen radius along the centre line", fontsize=10)
    else:
        ax_r.text(0.5, 0.5, "no radius profile", ha="center", va="center", color="0.5")
        ax_r.set_axis_off()
    ax_r.tick_params(labelsize=7)
    ax_r.grid(alpha=0.3)
    fig.tight_layout()
    return figure_uri(fig)


def _unregistered(cameras: dict | None, summary: dict) -> str:
    if cameras is not None:
        missing = [f["index"] for f in cameras.get("frames", []) if not f.get("registered")]
        runs: list[str] = []
        for i in missing:
            if runs and runs[-1].split("-")[-1] == str(i - 1):
                runs[-1] = f"{runs[-1].split('-')[0]}-{i}"
            else:
                runs.append(str(i))
        return ", ".join(runs) or "none"
    return str(summary.get("unregistered") or "none")


def section_poses(data: CaseData, info: ReportInfo) -> str | None:
    parts = []
    cams = data.cameras
    if cams is not None:
        ids, centres, views = camera_arrays(cams)
        if len(centres):
            gt = None
            try:
                gt = gt_centres(data, ids)
            except Exception:  # noqa: BLE001 - GT overlay is optional
                gt = None
            uri = plot_trajectory(centres, views, data.centerline, gt, data.units)
            caption = (
                "Camera centres (coloured by frame order, arrows: viewing direction) and the "
                "lumen centre line with its radius"
                + ("; dashed: ground-truth trajectory" if gt is not None else "")
                + "."
            )
            parts.append(figure_html(uri, caption, "wide"))
        else:
            parts.append(not_available("no registered camera in cameras.json"))
    else:
        parts.append(not_available("02_poses/cameras.json is missing"))

    pos = data.summary("poses")
    rows = []
    if pos:
        rows += [
            ("Pose source", html.escape(str(pos.get("source", "—")))),
            (
                "Registered",
                f"{fmt(pos.get('registered'))} of {fmt(pos.get('total'))} "
                f"({fmt(100 * pos.get('registered_fraction', 0.0))}%)",
            ),
            ("Unregistered frames", html.escape(_unregistered(cams, pos))),
            ("Camera model", html.escape(f"{pos.get('camera_model', '—')}")),
            ("Sparse points", fmt(pos.get("points"))),
        ]
        if pos.get("mean_reproj_px") is not None:
            rows.append(("Mean reprojection error", fmt(pos.get("mean_reproj_px"), "px")))
        if pos.get("ate_mm") is not None:
            rows += [
                ("ATE (RMSE after sim(3))", fmt(pos.get("ate_mm"), "mm")),
                ("ATE, % of the path", fmt(pos.get("ate_percent_of_path"), "%")),
                ("RRE (frame to frame)", fmt(pos.get("rre_deg"), "°")),
                ("Ground-truth path length", fmt(pos.get("gt_path_length_mm"), "mm")),
            ]
        else:
            rows.append(("ATE / RRE", "not available (no ground-truth poses)"))
    cl = data.summary("centerline")
    if cl:
        u = str(cl.get("units", data.units))
        rows += [
            ("Lumen model", html.escape(str(cl.get("kind", "—")))),
            ("Centre line length", fmt(cl.get("length"), u)),
            ("Mean radius", fmt(cl.get("mean_radius"), u)),
            ("Radius from", fmt(cl.get("radius_note") or cl.get("radius_source"))),
        ]
        if cl.get("centerline_mean_dist_pct_of_radius") is not None:
            rows += [
                (
                    "Centre line vs truth",
                    fmt(cl.get("centerline_mean_dist_pct_of_radius"), "% of radius"),
                ),
                ("Radius error vs truth", fmt(cl.get("radius_error_pct"), "%")),
            ]
    if rows:
        parts.append("<h3>Poses and centre line</h3>" + kv_table(rows))
    png = data.file("centerline", "centerline.png")
    if png is not None:
        uri = file_image_uri(png, 1100)
        if uri:
            parts.append(
                "<details><summary>Centre line stage's own diagnostic plot</summary>"
                + figure_html(uri, "03_centerline/centerline.png", "wide")
                + "</details>"
            )
    if cams is None and not rows:
        return None
    return "".join(parts)


# --- nerf -----------------------------------------------------------------------------------------


def read_train_log(path: Path) -> dict[str, list[float]]:
    """train_log.csv as columns of floats (empty cells become NaN)."""
    cols: dict[str, list[float]] = {}
    with open(path, newline="") as fh:
        for row in csv.DictReader(fh):
            for k, v in row.items():
                if k is None:
                    continue
                try:
                    x = float(v) if v not in (None, "") else math.nan
                except ValueError:
                    x = math.nan
                cols.setdefault(k, []).append(x)
    return cols


def plot_train_log(cols: dict[str, list[float]]) -> str | None:
    steps = cols.get("step")
    if not steps:
        return None
    fig = _figure(11.0, 3.4)
    ax = fig.add_subplot(1, 2, 1)
    drawn = False
    for key, values in cols.items():
        if key in ("step", "psnr", "lr", "time_s", "elapsed_s") or not values:
            continue
        y = np.asarray(values, dtype=np.float64)
        if np.isfinite(y).any() and np.nanmax(y) > 0:
            ax.plot(steps, np.where(y > 0, y, np.nan), label=key, lw=1.2)
            drawn = True
    if drawn:
        ax.set_yscale("log")
        ax.legend(fontsize=7)
    ax.set_xlabel("step", fontsize=8)
    ax.set_ylabel("loss", fontsize=8)
    ax.grid(alpha=0.3)
    ax2 = fig.add_subplot(1, 2, 2)
    if "psnr" in cols:
        ax2.plot(steps, cols["psnr"], color="#1f4e79", lw=1.2)
    ax2.set_xlabel("step", fontsize=8)
    ax2.set_ylabel("train PSNR (dB)", fontsize=8)
    ax2.grid(alpha=0.3)
    fig.tight_layout()
    return figure_uri(fig)


def section_nerf(data: CaseData, info: ReportInfo) -> str | None:
    parts = []
    png = data.file("nerf", "loss.png")
    uri = file_image_uri(png, 1100) if png is not None else None
    if uri is None:
        log = data.file("nerf", "train_log.csv")
        if log is not None:
            uri = plot_train_log(read_train_log(log))
    if uri is not None:
        parts.append(figure_html(uri, "Training losses (log scale) and training PSNR.", "wide"))
    else:
        parts.append(not_available("no loss curves (04_nerf/loss.png or train_log.csv)"))
    held = data.file("nerf", "heldout.png")
    if held is not None:
        uri = file_image_uri(held, 1100, "jpg", data.cfg.jpeg_quality)
        if uri:
            parts.append(
                figure_html(
                    uri,
                    "Held-out frames (every 8th, not trained on): image, rendering, rendered "
                    "depth, ground-truth depth (when available).",
                    "wide",
                )
            )
    s = data.summary("nerf")
    rows = []
    if s:
        rows += [
            ("Steps", fmt(s.get("steps"))),
            (
                "Training / held-out frames",
                f"{fmt(s.get('train_frames'))} / {fmt(s.get('heldout_frames'))}",
            ),
            ("Training time", fmt(s.get("train_s"), "s")),
            ("Throughput", fmt(s.get("rays_per_s"), "rays/s")),
            ("Render time per frame", fmt(s.get("render_ms"), "ms")),
            ("Device", html.escape(str(s.get("device", "—")))),
        ]
        if s.get("resumed_from"):
            rows.append(("Resumed from step", fmt(s.get("resumed_from"))))
    nm = data.nerf_metrics or {}
    if nm.get("psnr") is not None or s.get("heldout_psnr") is not None:
        rows.append(("Held-out PSNR", fmt(nm.get("psnr", s.get("heldout_psnr")), "dB")))
    if rows:
        parts.append(kv_table(rows))
    if isinstance(nm.get("depth"), dict):
        parts.append(
            "<h3>Rendered depth on held-out frames</h3>"
            + depth_metric_table(nm["depth"], data.units)
        )
    if png is None and held is None and not s:
        return None
    return "".join(parts)


# --- depth ----------------------------------------------------------------------------------------


def depth_metric_table(metrics: dict, units: str = "") -> str:
    """Both protocols side by side; a protocol missing from `metrics` shows '—'."""
    protos = [(k, label) for k, label in DEPTH_PROTOCOLS if isinstance(metrics.get(k), dict)]
    if not protos:
        flat = {k: v for k, v in metrics.items() if isinstance(v, int | float)}
        if not flat:
            return not_available("no depth metrics")
        protos = [("", "value")]
        metrics = {"": flat}
    keys = [m for m in DEPTH_METRICS if any(m[0] in metrics[p] for p, _ in protos)]
    known = {m[0] for m in DEPTH_METRICS}
    extra = sorted(
        {
            k
            for p, _ in protos
            for k, v in metrics[p].items()
            if k not in known and isinstance(v, int | float) and not isinstance(v, bool)
        }
    )
    head = "".join(f"<th>{html.escape(label)}</th>" for _, label in protos)
    rows = []
    for key, label, higher in keys:
        arrow = "↑" if higher else "↓"
        unit = units if key in ("rmse",) else ""
        cells = "".join(f'<td class="num">{fmt(metrics[p].get(key), unit)}</td>' for p, _ in protos)
        rows.append(f'<tr><th>{label} <span class="muted">{arrow}</span></th>{cells}</tr>')
    for key in extra:
        cells = "".join(f'<td class="num">{fmt(metrics[p].get(key))}</td>' for p, _ in protos)
        rows.append(f"<tr><th>{html.escape(key)}</th>{cells}</tr>")
    return f'<table class="grid metrics"><thead><tr><th></th>{head}</tr></thead>' + (
        "<tbody>" + "".join(rows) + "</tbody></table>"
    )


def per_frame_series(per_frame: Any, metric: str = "abs_rel") -> dict[str, tuple[list, list]]:
    """`metric` per frame, by protocol, from the shapes a per_frame block may take:
    {"index": [...], "median_scaled": {"abs_rel": [...]}, ...}, {"abs_rel": [...]}, or a list
    of per-frame dicts (optionally with "index" and protocol sub-dicts)."""
    out: dict[str, tuple[list, list]] = {}
    if isinstance(per_frame, dict):
        index = per_frame.get("index") or per_frame.get("frames") or per_frame.get("frame")
        for proto, label in DEPTH_PROTOCOLS:
            sub = per_frame.get(proto)
            if isinstance(sub, dict) and isinstance(sub.get(metric), list):
                y = sub[metric]
                x = sub.get("index") or index or list(range(len(y)))
                out[label] = (list(x), list(y))
            elif isinstance(sub, list) and sub and isinstance(sub[0], dict):
                inner = per_frame_series(sub, metric)
                if inner:
                    out[label] = next(iter(inner.values()))
        if not out and isinstance(per_frame.get(metric), list):
            y = per_frame[metric]
            out["per frame"] = (list(index or range(len(y))), list(y))
    elif isinstance(per_frame, list) and per_frame and isinstance(per_frame[0], dict):
        for proto, label in DEPTH_PROTOCOLS:
            pts = [
                (f.get("index", i), f[proto][metric])
                for i, f in enumerate(per_frame)
                if isinstance(f.get(proto), dict) and f[proto].get(metric) is not None
            ]
            if pts:
                out[label] = ([p[0] for p in pts], [p[1] for p in pts])
        if not out:
            pts = [
                (f.get("index", i), f[metric])
                for i, f in enumerate(per_frame)
                if f.get(metric) is not None
            ]
            if pts:
                out["per frame"] = ([p[0] for p in pts], [p[1] for p in pts])
    return out


def plot_per_frame(series: dict[str, tuple[list, list]], metric: str = "AbsRel") -> str:
    fig = _figure(11.0, 2.4)
    ax = fig.add_subplot(1, 1, 1)
    for label, (x, y) in series.items():
        y_arr = np.asarray(y, dtype=np.float64)
        ax.plot(
            x, y_arr, marker="o", ms=2.5, lw=1.0, label=f"{label} (mean {np.nanmean(y_arr):.3g})"
        )
    ax.set_xlabel("frame", fontsize=8)
    ax.set_ylabel(metric, fontsize=8)
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    return figure_uri(fig)


def depth_files(folder: Path) -> dict[int, Path]:
    """05_depth/depth/<index>.npy by endopipe frame index."""
    out = {}
    for p in sorted((folder / "depth").glob("*.npy")):
        if p.stem.isdigit():
            out[int(p.stem)] = p
    return out


def pick_frames(indices: list[int], count: int) -> list[int]:
    if count <= 0 or not indices:
        return []
    if len(indices) <= count:
        return list(indices)
    pos = np.linspace(0, len(indices) - 1, count).round().astype(int)
    return [indices[p] for p in dict.fromkeys(pos.tolist())]


@dataclass
class PreviewRow:
    index: int
    source_index: int | None
    rgb: np.ndarray | None
    depth: np.ndarray  # as estimated (scaled to GT by its median ratio when GT exists)
    gt: np.ndarray | None
    error: np.ndarray | None  # abs-rel error, NaN where not evaluated
    scale: float | None


def preview_row(data: CaseData, index: int, path: Path) -> PreviewRow:
    depth = np.load(path).astype(np.float32)
    h, w = depth.shape[:2]
    entry = data.frame_entry(index)
    rgb = None
    mask = None
    if entry is not None and data.folder("ingest") is not None:
        img = cv2.imread(str(data.folder("ingest") / entry["file"]), cv2.IMREAD_COLOR)
        if img is not None:
            rgb = cv2.cvtColor(
                cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA), cv2.COLOR_BGR2RGB
            )
        if entry.get("mask"):
            m = cv2.imread(str(data.folder("ingest") / entry["mask"]), cv2.IMREAD_GRAYSCALE)
            if m is not None:
                mask = cv2.resize(m, (w, h), interpolation=cv2.INTER_NEAREST) > 127
    src = entry.get("source_index") if entry else None
    gt_depth = error = scale = None
    gt = data.ground_truth()
    if gt is not None and src is not None:
        g = gt.depth(int(src))
        if g is not None:
            g = np.asarray(g, dtype=np.float32)
            if g.shape != depth.shape:
                g = cv2.resize(g, (w, h), interpolation=cv2.INTER_NEAREST)
            gt_depth = g
            valid = (g > 0) & (depth > 0) & np.isfinite(depth)
            if mask is not None:
                valid &= mask
            if valid.sum() > 10:
                scale = float(np.median(g[valid]) / np.median(depth[valid]))
                error = np.full(depth.shape, np.nan, np.float32)
                error[valid] = np.abs(depth[valid] * scale - g[valid]) / g[valid]
    shown = depth * scale if scale is not None else depth
    return PreviewRow(index, src, rgb, shown, gt_depth, error, scale)


def plot_depth_preview(rows: list[PreviewRow], units: str, error_max: float) -> str:
    from matplotlib import colormaps

    has_gt = any(r.gt is not None for r in rows)
    ncols = 4 if has_gt else 2
    h, w = rows[0].depth.shape[:2]
    tile_w = 3.1
    fig = _figure(tile_w * ncols + 0.8, len(rows) * tile_w * h / w + 0.5)
    turbo = colormaps["turbo"].with_extremes(bad="black")
    inferno = colormaps["inferno"].with_extremes(bad="#202020")
    for r_i, row in enumerate(rows):
        valid = (row.depth > 0) & np.isfinite(row.depth)
        ref = row.gt[row.gt > 0] if row.gt is not None and (row.gt > 0).any() else None
        ref = ref if ref is not None else row.depth[valid]
        lo, hi = np.percentile(ref, [2, 98]) if ref.size else (0.0, 1.0)
        hi = hi if hi > lo else lo + 1e-6
        axes = [fig.add_subplot(len(rows), ncols, r_i * ncols + c + 1) for c in range(ncols)]
        src = f", source {row.source_index}" if row.source_index is not None else ""
        if row.rgb is not None:
            axes[0].imshow(row.rgb, **NEAREST)
        else:
            axes[0].text(0.5, 0.5, "no image", ha="center", va="center", color="0.5")
        axes[0].set_title(f"frame {row.index}{src}", fontsize=8)
        label = "depth (median-scaled to GT)" if row.scale is not None else "estimated depth"
        im = axes[1].imshow(
            np.ma.masked_where(~valid, row.depth), cmap=turbo, vmin=lo, vmax=hi, **NEAREST
        )
        axes[1].set_title(label, fontsize=8)
        cb = fig.colorbar(im, ax=axes[1], fraction=0.046, pad=0.02)
        cb.ax.tick_params(labelsize=6)
        cb.set_label(units, fontsize=6)
        if has_gt:
            if row.gt is not None:
                im = axes[2].imshow(
                    np.ma.masked_where(row.gt <= 0, row.gt), cmap=turbo, vmin=lo, vmax=hi, **NEAREST
                )
                cb = fig.colorbar(im, ax=axes[2], fraction=0.046, pad=0.02)
                cb.ax.tick_params(labelsize=6)
                axes[2].set_title("ground-truth depth", fontsize=8)
            else:
                axes[2].text(0.5, 0.5, "no GT for this frame", ha="center", va="center")
            if row.error is not None:
                err = np.ma.masked_invalid(row.error)
                im = axes[3].imshow(err, cmap=inferno, vmin=0, vmax=error_max, **NEAREST)
                cb = fig.colorbar(im, ax=axes[3], fraction=0.046, pad=0.02)
                cb.ax.tick_params(labelsize=6)
                axes[3].set_title(f"abs-rel error (mean {np.nanmean(row.error):.3f})", fontsize=8)
            else:
                axes[3].text(0.5, 0.5, "not evaluated", ha="center", va="center", color="0.5")
        for ax in axes:
            ax.set_xticks([])
            ax.set_yticks([])
    fig.tight_layout()
    return figure_uri(fig, "jpg", 90)


def section_depth(data: CaseData, info: ReportInfo) -> str | None:
    folder = data.folder("depth")
    if folder is None:
        return None
    parts = []
    dm = data.depth_metrics
    if dm is not None:
        parts.append(
            '<h3>Depth accuracy</h3><p class="note">Per frame, on pixels with valid ground '
            "truth, averaged over frames. <b>Per-frame median scaling</b> is the standard "
            "monocular protocol (Monodepth2 / Endo-SfM); <b>one scale for the sequence</b> is "
            "stricter and rewards a 3D-consistent reconstruction.</p>"
        )
        parts.append(depth_metric_table(dm, data.units))
        if isinstance(dm.get("frames"), int):
            parts.append(f'<p class="note">{dm["frames"]} frame(s) evaluated.</p>')
        img_rows = []
        for key, label, unit in (("psnr", "PSNR", "dB"), ("ssim", "SSIM", "")):
            value = image_metric(data, key)
            img_rows.append((label, fmt(value, unit) if value is not None else "not available"))
        held = dm.get("heldout_frames")
        if isinstance(held, list):
            img_rows.append(("Held-out frames", html.escape(", ".join(map(str, held)) or "none")))
        parts.append("<h3>Image quality (held-out frames)</h3>" + kv_table(img_rows))
        series = per_frame_series(dm.get("per_frame"))
        if series:
            parts.append(figure_html(plot_per_frame(series), "AbsRel per frame.", "wide"))
    else:
        reason = (
            "no ground truth to evaluate against"
            if info.gt_kind == "none"
            else "05_depth/metrics.json is missing"
        )
        parts.append("<h3>Depth accuracy</h3>" + not_available(reason))

    parts.append("<h3>Previews</h3>" + depth_previews(data, folder))

    video = data.file("depth", "preview.mp4")
    if video is not None and data.cfg.include_video:
        size_mb = video.stat().st_size / 2**20
        if size_mb <= data.cfg.max_video_mb:
            b64 = base64.b64encode(video.read_bytes()).decode()
            parts.append(
                '<h3>Preview video</h3><video class="wide" controls loop muted playsinline '
                f'src="data:video/mp4;base64,{b64}"></video>'
                '<p class="note">05_depth/preview.mp4: RGB | depth | error.</p>'
            )
        else:
            parts.append(
                "<h3>Preview video</h3>"
                + not_available(
                    f"preview.mp4 is {size_mb:.1f} MB (over max_video_mb = "
                    f"{data.cfg.max_video_mb:g}); open it next to the report: {video}"
                )
            )
    return "".join(parts)


def depth_previews(data: CaseData, folder: Path) -> str:
    files = depth_files(folder)
    picks = pick_frames(sorted(files), data.cfg.max_preview_frames)
    if not picks:
        return not_available("no depth maps in 05_depth/depth/")
    rows, bad = [], []
    for i in picks:
        try:
            row = preview_row(data, i, files[i])
        except Exception as e:  # noqa: BLE001 - one unreadable map costs one row
            bad.append(f"frame {i}: {_one_line(e)}")
            continue
        if row.depth.ndim != 2:
            bad.append(f"frame {i}: depth map of shape {row.depth.shape}")
            continue
        rows.append(row)
    note = not_available("; ".join(bad)) if bad else ""
    if not rows:
        return note
    shapes = {r.depth.shape for r in rows}
    if len(shapes) > 1:
        rows = [r for r in rows if r.depth.shape == rows[0].depth.shape]
    if data.cfg.preview_width and rows[0].depth.shape[1] > data.cfg.preview_width:
        rows = [_shrink_row(r, data.cfg.preview_width) for r in rows]
    uri = plot_depth_preview(rows, data.units, data.cfg.error_max)
    cap = "Depth previews: RGB | depth (turbo colour map, near = blue)"
    if any(r.gt is not None for r in rows):  # four columns
        cap += (
            " | ground truth (same colour scale) | abs-rel error after per-frame median "
            f"scaling (0 to {data.cfg.error_max:g})"
        )
    has_gt = any(r.gt is not None for r in rows)
    return figure_html(uri, cap + ".", "wide" if has_gt else "medium") + note


def _shrink_row(row: PreviewRow, width: int) -> PreviewRow:
    h, w = row.depth.shape[:2]
    size = (width, max(1, round(h * width / w)))

    def near(a: np.ndarray | None) -> np.ndarray | None:
        return None if a is None else cv2.resize(a, size, interpolation=cv2.INTER_NEAREST)

    rgb = None if row.rgb is None else cv2.resize(row.rgb, size, interpolation=cv2.INTER_AREA)
    return PreviewRow(
        row.index, row.source_index, rgb, near(row.depth), near(row.gt), near(row.error), row.scale
    )


# --- mesh -----------------------------------------------------------------------------------------


def image_metric(data: CaseData, key: str) -> float | None:
    """PSNR / SSIM of held-out frames: the depth stage's, else the NeRF stage's."""
    for block in (data.depth_metrics or {}, data.nerf_metrics or {}):
        for k in (key, f"heldout_{key}"):
            value = block.get(k)
            if isinstance(value, int | float) and not isinstance(value, bool):
                return float(value)
    return None


def _flat_numbers(data: dict, prefix: str = "") -> dict[str, float]:
    out: dict[str, float] = {}
    for k, v in data.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(_flat_numbers(v, key + "."))
        elif isinstance(v, int | float) and not isinstance(v, bool):
            out[key] = float(v)
    return out


def _first(flat: dict[str, float], needles: tuple[str, ...]) -> tuple[str, float] | None:
    for k, v in flat.items():
        low = k.lower().replace("-", "_")
        if any(n.replace("-", "_") in low for n in needles):
            return k, v
    return None


MESH_LABELS = (
    ("chamfer", "Chamfer distance (mean of both directions)"),
    ("fscore", "F-score"),
    ("f_score", "F-score"),
    ("precision", "Precision"),
    ("recall", "Recall"),
    ("accuracy", "Accuracy (est. → GT)"),
    ("completeness", "Completeness (GT → est.)"),
    ("threshold", "F-score threshold"),
    ("vertices", "Vertices"),
    ("faces", "Faces"),
    ("watertight", "Watertight"),
)


def mesh_metric_rows(metrics: dict, units: str) -> list[tuple[str, str]]:
    rows = []
    for key, value in _flat_numbers(metrics).items():
        low = key.lower()
        label = next((lab for needle, lab in MESH_LABELS if needle in low), None)
        shown = key if label is None else f"{label} [{key}]"
        if "pct" in low or "percent" in low:
            unit = "%"
        elif any(n in low for n in ("fscore", "f_score", "precision", "recall", "scale", "_s")):
            unit = ""
        elif any(n in low for n in ("chamfer", "threshold", "accuracy", "complet", "radius")):
            unit = units
        elif "depth" in low:
            unit = units
        else:
            unit = ""
        if float(value).is_integer() and any(n in low for n in ("vertices", "faces", "count")):
            rows.append((shown, fmt(int(value))))
        else:
            rows.append((shown, fmt(value, unit)))
    for key, value in metrics.items():
        if isinstance(value, str | bool) and key not in ("evaluated", "reason"):
            rows.append((key.replace("_", " "), fmt(value)))
    return rows


def distance_band_table(bands: Any, radius: Any, units: str) -> str:
    """metrics.json's by_camera_distance as a table: where the mesh can be trusted."""
    if not isinstance(bands, list) or not bands:
        return ""

    def edge(v: Any) -> str:
        if v is None:
            return "∞"
        return f"{v / radius:.1f}" if isinstance(radius, int | float) and radius > 0 else fmt(v)

    rows = []
    for b in bands:
        if not isinstance(b, dict):
            continue
        cells = [
            f"{edge(b.get('from'))}–{edge(b.get('to'))}",
            fmt(b.get("chamfer"), units),
            fmt(b.get("chamfer_pct_radius"), "%"),
            fmt(b.get("accuracy"), units),
            fmt(b.get("completeness"), units),
            fmt(100.0 * b["gt_share"], "%") if isinstance(b.get("gt_share"), float) else "—",
        ]
        rows.append("<tr>" + "".join(f'<td class="num">{c}</td>' for c in cells) + "</tr>")
    head = "".join(
        f"<th>{h}</th>"
        for h in (
            "nearest camera (radii)",
            "Chamfer",
            "% of radius",
            "accuracy",
            "completeness",
            "share of GT surface",
        )
    )
    return (
        '<p class="note">By distance of the surface to the nearest camera centre: depth error '
        "grows with distance, so the surface the scope passed close to is the part to trust."
        f'</p><table class="grid metrics"><thead><tr>{head}</tr></thead><tbody>'
        + "".join(rows)
        + "</tbody></table>"
    )


def decimate(
    vertices: np.ndarray, faces: np.ndarray, max_faces: int, colors: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """At most `max_faces` faces by vertex clustering on a grid (dependency-free; keeps the
    shape, merges detail). The cell starts where a surface of this area would give about
    `max_faces` faces and grows until it does. Colours are averaged per cluster."""
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    if len(f) <= max_faces:
        return v, f, colors
    vmin = v.min(0)
    diag = float(np.linalg.norm(np.ptp(v, axis=0))) or 1.0
    tri = v[f]
    area = 0.5 * float(
        np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum()
    )
    del tri
    cell = max(math.sqrt(2.0 * area / max_faces), diag * 1e-5)

    def cluster(size: float) -> tuple[np.ndarray, np.ndarray]:
        q = np.floor((v - vmin) / size).astype(np.int64)
        dims = q.max(0) + 1
        key = (q[:, 0] * dims[1] + q[:, 1]) * dims[2] + q[:, 2]
        _, inv = np.unique(key, return_inverse=True)
        nf = inv.reshape(-1)[f]
        keep = (nf[:, 0] != nf[:, 1]) & (nf[:, 1] != nf[:, 2]) & (nf[:, 0] != nf[:, 2])
        return inv.reshape(-1), nf[keep]

    inv, nf = cluster(cell)
    for _ in range(60):
        if len(nf) <= max_faces or cell > diag:
            break
        cell *= 1.1
        inv, nf = cluster(cell)
    srt = np.sort(nf, axis=1)
    _, first = np.unique(srt, axis=0, return_index=True)
    nf = nf[np.sort(first)]
    n = int(inv.max()) + 1
    counts = np.bincount(inv, minlength=n).astype(np.float64)[:, None]
    nv = np.zeros((n, 3))
    np.add.at(nv, inv, v)
    nv /= np.maximum(counts, 1)
    nc = None
    if colors is not None:
        c = np.asarray(colors, np.float64)
        nc = np.zeros((n, c.shape[1]))
        np.add.at(nc, inv, c)
        nc = (nc / np.maximum(counts, 1)).round().astype(np.uint8)
    used = np.unique(nf)
    remap = np.full(n, -1, np.int64)
    remap[used] = np.arange(len(used))
    return nv[used], remap[nf], None if nc is None else nc[used]


def load_mesh(path: Path, max_faces: int):
    """(vertices, faces, vertex colours RGB uint8 or None, original face count)."""
    import trimesh

    mesh = trimesh.load(path, process=False, force="mesh")
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ValueError(f"{path.name} holds no triangles")
    colors = None
    if getattr(mesh.visual, "kind", None) == "vertex":
        vc = np.asarray(mesh.visual.vertex_colors)[:, :3]
        if len(vc) == len(mesh.vertices) and not np.all(vc == vc[0]):
            colors = vc.astype(np.uint8)
    v, f, c = decimate(mesh.vertices, mesh.faces, max_faces, colors)
    return v, f, c, len(mesh.faces)


def principal_axes(vertices: np.ndarray) -> np.ndarray:
    """Rows: the main, second and third axes of the vertex cloud (right-handed)."""
    sample = vertices[:: max(1, len(vertices) // 20000)]
    _, _, vt = np.linalg.svd(sample - sample.mean(0), full_matrices=False)
    axes = np.eye(3) if vt.shape[0] < 3 else vt.copy()
    axes[2] = np.cross(axes[0], axes[1])
    return axes


def render_mesh_view(
    vertices: np.ndarray,
    faces: np.ndarray,
    colors: np.ndarray | None,
    right: np.ndarray,
    up: np.ndarray,
    width: int = 460,
    supersample: int = 2,
) -> np.ndarray:
    """An orthographic, two-sided rendering (painter's algorithm with OpenCV): a head light
    plus a key light from the upper left. The height follows the mesh's extent (clamped)."""
    fwd = np.cross(right, -up)  # camera looks along fwd, image x = right, image y = -up
    x, y, z = vertices @ right, -(vertices @ up), vertices @ fwd
    x = x - (x.max() + x.min()) / 2
    y = y - (y.max() + y.min()) / 2
    ex, ey = max(float(np.ptp(x)), 1e-12), max(float(np.ptp(y)), 1e-12)
    height = int(np.clip(width * ey / ex, 0.3 * width, 0.9 * width))
    w, h = width * supersample, height * supersample
    s = 0.9 * min(w / ex, h / ey)
    px = np.stack([x * s + w / 2, y * s + h / 2], 1)
    tri = vertices[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-20)
    key = -fwd + 0.6 * up - 0.5 * right
    key /= np.linalg.norm(key)
    shade = 0.22 + 0.5 * np.abs(n @ fwd) + 0.35 * np.abs(n @ key)
    base = (
        colors[faces].mean(1) if colors is not None else np.tile(TISSUE_RGB, (len(faces), 1))
    ).astype(np.float64)
    rgb = np.clip(base * shade[:, None], 0, 255).astype(np.uint8)
    order = np.argsort(-z[faces].mean(1))  # far first
    img = np.full((h, w, 3), 250, np.uint8)
    pts = np.round(px[faces] * 4).astype(np.int32)  # 2 fractional bits
    for i in order:
        cv2.fillConvexPoly(img, pts[i], rgb[i].tolist(), lineType=cv2.LINE_AA, shift=2)
    return cv2.resize(img, (width, height), interpolation=cv2.INTER_AREA)


def mesh_viewer_page(
    vertices: np.ndarray,
    faces: np.ndarray,
    colors: np.ndarray | None,
    path_points: np.ndarray | None = None,
) -> str:
    """trimesh's self-contained three.js page for the mesh (double-sided, oblique initial view)
    and the camera path. Raises when the page would need the network."""
    import trimesh
    from trimesh.scene.cameras import look_at
    from trimesh.viewer.notebook import scene_to_html

    nv = len(vertices)
    rgb = np.asarray(colors if colors is not None else np.tile(TISSUE_RGB, (nv, 1)), np.uint8)
    mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=False)
    # A matte, double-sided material (glTF's default is metallic: black without an environment
    # map; a lumen is seen from inside and outside); colours as a vertex attribute.
    material = trimesh.visual.material.PBRMaterial(
        baseColorFactor=[255, 255, 255, 255],
        metallicFactor=0.0,
        roughnessFactor=0.85,
        doubleSided=True,
    )
    mesh.visual = trimesh.visual.TextureVisuals(material=material)
    mesh.visual.vertex_attributes["color"] = np.column_stack([rgb, np.full(nv, 255, np.uint8)])
    _ = mesh.vertex_normals  # cached normals are exported: smooth shading
    scene = trimesh.Scene(mesh)
    if path_points is not None and len(path_points) >= 2:
        try:
            path = trimesh.load_path(np.asarray(path_points, np.float64))
            path.colors = np.tile([31, 78, 121, 255], (len(path.entities), 1))
            scene.add_geometry(path)
        except Exception:  # noqa: BLE001 - the path is decoration
            pass
    axes = principal_axes(vertices)
    back = 0.7 * axes[1] + 0.45 * axes[0] + 0.6 * axes[2]  # from the centre towards the eye
    back /= np.linalg.norm(back)
    right = np.cross(axes[2], back)
    right /= np.linalg.norm(right)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2] = right, np.cross(back, right), back
    scene.camera_transform = look_at(vertices, scene.camera.fov, rotation=pose)
    page = scene_to_html(scene)
    if not page_is_self_contained(page):
        raise RuntimeError("trimesh's viewer page loads scripts from the network")
    # Without WebGL, three.js throws in init(): say so instead of leaving a blank frame.
    page = page.replace(
        "init();</script>",
        "try{init();}catch(e){document.body.innerHTML='<p style=\"font:14px sans-serif;"
        "color:#6b7684;padding:16px\">3D viewer unavailable: '+e.message+' (needs WebGL). "
        "The static views below show the mesh.</p>';}</script>",
        1,
    )
    return page


_NETWORK_LOADS = (
    re.compile(r"<script[^>]+\bsrc\s*=", re.I),
    re.compile(r"<link[^>]+\bhref\s*=\s*[\"']?(https?:)?//", re.I),
    re.compile(r"\bimport\s*(\(|[^;]*?\bfrom\s*)[\"'](https?:)?//", re.I),
    re.compile(r"\bsrc\s*=\s*[\"'](https?:)?//", re.I),
)


def page_is_self_contained(page: str) -> bool:
    """True when an HTML page loads no script, style or image from elsewhere."""
    return not any(p.search(page) for p in _NETWORK_LOADS)


def section_mesh(data: CaseData, info: ReportInfo) -> str | None:
    folder = data.folder("mesh")
    if folder is None:
        return None
    parts = []
    mm = data.mesh_metrics
    if mm and mm.get("evaluated") is False:
        parts.append(
            "<h3>Surface accuracy</h3>"
            + not_available(f"not evaluated: {mm.get('reason') or 'no reason given'}")
        )
    elif mm:
        gt_units = str(getattr(data.ground_truth(), "units", "") or "mm")
        rows = mesh_metric_rows(mm, gt_units)
        parts.append(
            '<h3>Surface accuracy</h3><p class="note">After aligning the estimated trajectory '
            "to the ground truth with a similarity transform (Umeyama); Chamfer distance in the "
            "ground truth's units, F-score at the stated threshold.</p>"
            + (kv_table(rows) if rows else not_available("metrics.json holds no numbers"))
            + distance_band_table(mm.get("by_camera_distance"), mm.get("mean_radius"), gt_units)
        )
    else:
        reason = (
            "no ground-truth surface to compare with"
            if info.gt_kind == "none"
            else "06_mesh/metrics.json is missing"
        )
        parts.append("<h3>Surface accuracy</h3>" + not_available(reason))
    ms = data.summary("mesh")
    if ms:
        rows = [(k.replace("_", " "), fmt(v)) for k, v in ms.items() if not isinstance(v, dict)]
        if rows:
            parts.append(kv_table(rows))

    mesh_path = data.file("mesh", "mesh.ply")
    if mesh_path is None:
        parts.append("<h3>3D view</h3>" + not_available("06_mesh/mesh.ply is missing"))
        info.mesh_viewer = "none"
        return "".join(parts)
    try:
        v, f, c, n_orig = load_mesh(mesh_path, data.cfg.mesh_max_faces)
    except Exception as e:  # noqa: BLE001
        parts.append("<h3>3D view</h3>" + not_available(f"mesh.ply unreadable: {_one_line(e)}"))
        return "".join(parts)
    note = (
        f"{n_orig:,} faces, shown decimated to {len(f):,}"
        if len(f) < n_orig
        else f"{n_orig:,} faces"
    )
    viewer_html = ""
    info.mesh_viewer = "static"
    if data.cfg.include_mesh_viewer:
        path_points = None
        if data.cameras is not None:
            path_points = camera_arrays(data.cameras)[1]
        try:
            page = mesh_viewer_page(v, f, c, path_points)
            viewer_html = (
                '<iframe class="viewer" title="3D mesh viewer" '
                f'srcdoc="{html.escape(page, quote=True)}"></iframe>'
                '<p class="note">Interactive: drag to rotate, scroll to zoom, right-drag to pan. '
                "three.js is inlined (bundled with trimesh), so this works offline; it needs "
                "WebGL. Blue line: camera path.</p>"
            )
            info.mesh_viewer = "three.js (inlined from trimesh)"
        except Exception as e:  # noqa: BLE001 - fall back to the static views
            viewer_html = not_available(
                f"interactive viewer: {_one_line(e)}; static views below instead"
            )
    views = []
    if data.cfg.mesh_views:
        axes = principal_axes(v)
        defs = [
            ("side", axes[0], axes[1]),
            ("top", axes[0], axes[2]),
            ("end-on (along the lumen)", axes[1], axes[2]),
        ][: data.cfg.mesh_views]
        for label, right, up in defs:
            img = render_mesh_view(v, f, c, right, up)
            views.append(figure_html(image_uri(img, "jpg", data.cfg.jpeg_quality), label))
    parts.append(
        f'<h3>3D view</h3><p class="note">06_mesh/mesh.ply: {html.escape(note)}.</p>'
        + viewer_html
        + (f'<div class="views">{"".join(views)}</div>' if views else "")
        + (
            '<p class="note">Static orthographic views along the mesh\'s principal axes.</p>'
            if views
            else ""
        )
    )
    return "".join(parts)


# --- runs -----------------------------------------------------------------------------------------


def section_runs(data: CaseData, info: ReportInfo) -> str | None:
    from endopipe.pipeline.runner import RunRecord, package_versions

    parts = []
    runs = sorted((data.case_dir / "runs").glob("*.json"), reverse=True)
    records = []
    for path in runs[: data.cfg.max_runs]:
        try:
            records.append(RunRecord.model_validate_json(path.read_text()))
        except ValueError:
            continue
    if records:
        rows = []
        for r in records:
            ran = ", ".join(s.stage for s in r.stages if s.status == "ran") or "—"
            cached = ", ".join(s.stage for s in r.stages if s.status == "cached") or "—"
            failed = [s for s in r.stages if s.status == "failed"]
            state = badge("ok", "ok") if r.ok else badge("failed", "bad")
            why = html.escape(failed[0].reason) if failed else ""
            rows.append(
                f"<tr><td>{html.escape(r.started)}</td><td>{state} {why}</td>"
                f'<td class="num">{_duration(r.wall_s)}</td><td>{html.escape(ran)}</td>'
                f"<td>{html.escape(cached)}</td></tr>"
            )
        parts.append(
            '<table class="grid"><thead><tr><th>started</th><th>result</th><th>wall time</th>'
            "<th>ran</th><th>cached</th></tr></thead><tbody>" + "".join(rows) + "</tbody></table>"
        )
        packages = records[0].packages
        host, python = records[0].host, records[0].python
    else:
        parts.append(not_available("no run records in <case>/runs/"))
        packages, host, python = package_versions(), platform.node(), platform.python_version()
    env = ", ".join(f"{k} {v}" for k, v in sorted(packages.items()))
    parts.append(
        kv_table(
            [
                ("Host", html.escape(host)),
                ("Python", html.escape(python)),
                ("Packages", html.escape(env) or "—"),
            ]
        )
    )
    return "".join(parts)


# =============================================================================================
# Page template
# =============================================================================================

CSS = """
:root { --ink:#1b2430; --muted:#6b7684; --line:#e3e7ec; --bg:#f5f7fa; --brand:#123a5e;
  --ok:#1e7e4a; --warn:#b7791f; --bad:#b03a2e; }
* { box-sizing: border-box; }
body { margin:0; font: 14px/1.5 -apple-system, "Segoe UI", Roboto, "Helvetica Neue", Arial,
  "DejaVu Sans", sans-serif; color: var(--ink); background: var(--bg); }
header { background: linear-gradient(120deg, #0e2c49, #1d5283); color: #fff;
  padding: 22px 0 16px; }
header .wrap, main, nav .wrap { max-width: 1180px; margin: 0 auto; padding: 0 24px; }
header h1 { margin: 0 0 4px; font-size: 24px; font-weight: 600; letter-spacing: .2px; }
header .sub { color: #c9d7e6; font-size: 13px; word-break: break-all; }
nav { background: #fff; border-bottom: 1px solid var(--line); position: sticky; top: 0;
  z-index: 5; }
nav a { display: inline-block; padding: 9px 12px 8px; color: var(--brand);
  text-decoration: none; font-size: 13px; border-bottom: 2px solid transparent; }
nav a:hover { border-bottom-color: var(--brand); }
main { padding-top: 8px; padding-bottom: 40px; }
section { background: #fff; border: 1px solid var(--line); border-radius: 8px;
  margin: 18px 0; padding: 6px 22px 18px; box-shadow: 0 1px 2px rgba(16,38,60,.04); }
h2 { font-size: 18px; margin: 14px 0 12px; color: var(--brand); font-weight: 600; }
h3 { font-size: 14px; margin: 18px 0 8px; color: #2b3a4a; font-weight: 600; }
.cards { display: grid; grid-template-columns: repeat(auto-fill, minmax(160px, 1fr));
  gap: 12px; margin: 6px 0 14px; }
.card { border: 1px solid var(--line); border-radius: 8px; padding: 10px 14px;
  background: linear-gradient(180deg, #fff, #fafbfd); }
.card .label { font-size: 11px; text-transform: uppercase; letter-spacing: .6px;
  color: var(--muted); }
.card .value { font-size: 22px; font-weight: 600; margin-top: 2px; }
.card .note { font-size: 12px; color: var(--muted); min-height: 1em; }
table { border-collapse: collapse; margin: 6px 0 10px; font-size: 13px; }
table.kv th { text-align: left; font-weight: 500; color: var(--muted); padding: 4px 18px 4px 0;
  vertical-align: top; white-space: nowrap; }
table.kv td { padding: 4px 0; }
table.grid { width: 100%; }
table.grid th, table.grid td { border-bottom: 1px solid var(--line); padding: 6px 10px;
  text-align: left; vertical-align: top; }
table.grid thead th { background: #f0f3f7; font-weight: 600; font-size: 12px; color: #3a4a5c; }
table.grid tbody tr:nth-child(even) { background: #fafbfc; }
table.grid tfoot th, table.grid tfoot td { font-weight: 600; border-top: 2px solid var(--line); }
table.metrics { width: auto; min-width: 520px; }
td.num { text-align: right; font-variant-numeric: tabular-nums; white-space: nowrap; }
.unit { color: var(--muted); font-size: 12px; }
.muted { color: var(--muted); }
.bar { height: 4px; background: #edf1f5; border-radius: 2px; margin-top: 3px; }
.bar span { display: block; height: 4px; background: #2f6da3; border-radius: 2px; }
.badge { display: inline-block; padding: 1px 8px; border-radius: 10px; font-size: 12px;
  font-weight: 600; }
.badge.ok { background: #e3f4ea; color: var(--ok); }
.badge.warn { background: #fdf1dc; color: var(--warn); }
.badge.bad { background: #fbe5e2; color: var(--bad); }
.badge.muted { background: #eef1f4; color: var(--muted); }
.na { border: 1px dashed #cfd6de; background: #fafbfc; color: var(--muted); border-radius: 6px;
  padding: 10px 14px; margin: 8px 0; font-size: 13px; }
.na b { color: #55606c; }
p.note { color: var(--muted); font-size: 12.5px; margin: 6px 0 10px; }
figure { margin: 10px 0; }
figure img, video.wide { max-width: 100%; height: auto; border: 1px solid var(--line);
  border-radius: 4px; background: #fff; }
figure.wide img { width: 100%; }
figure.medium img { width: 100%; max-width: 860px; }
figcaption { color: var(--muted); font-size: 12.5px; margin-top: 4px; }
.views { display: grid; grid-template-columns: repeat(auto-fill, minmax(300px, 1fr));
  gap: 12px; }
iframe.viewer { width: 100%; height: 520px; border: 1px solid var(--line); border-radius: 6px;
  background: #fff; }
details { margin: 6px 0; }
details summary { cursor: pointer; color: var(--brand); font-size: 13px; }
pre { background: #f6f8fa; border: 1px solid var(--line); border-radius: 6px; padding: 10px;
  font-size: 12px; overflow: auto; max-height: 360px; }
code { font-family: "SFMono-Regular", Menlo, Consolas, "DejaVu Sans Mono", monospace;
  font-size: 12px; background: #f2f4f7; padding: 1px 4px; border-radius: 3px; }
footer { color: var(--muted); font-size: 12px; text-align: center; padding: 10px 0 30px; }
@media print { nav { display: none; } section { break-inside: avoid; box-shadow: none; }
  iframe.viewer { display: none; } }
"""

PAGE = """<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<meta name="generator" content="endopipe {version}">
<title>{title}</title>
<style>{css}</style>
</head>
<body>
<header><div class="wrap"><h1>{title}</h1><div class="sub">{subtitle}</div></div></header>
<nav><div class="wrap">{nav}</div></nav>
<main>
{body}
</main>
<footer>Generated by endopipe {version} on {generated}. Self-contained page: no network access
needed.</footer>
</body>
</html>
"""
