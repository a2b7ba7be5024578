"""The page's sections. Each reads the case's views and returns HTML, or None when it has
nothing at all to show (the page then says "not available")."""

from __future__ import annotations

import datetime as dt
import os
import platform
from typing import Any

import cv2
import numpy as np
import psutil

from endopipe.stages.report import pose_verdict as pv
from endopipe.stages.report.figures import (
    Curve,
    PreviewRow,
    plot_depth_preview,
    plot_per_frame,
    plot_trajectory,
)
from endopipe.stages.report.guesses import comparison, verdicts
from endopipe.stages.report.images import file_image_uri, image_uri, video_uri
from endopipe.stages.report.kit import (
    badge,
    card,
    details_json,
    duration,
    figure_html,
    fmt,
    grid,
    grouped_table,
    kv_table,
    not_available,
    one_line,
    stages_table,
    text,
    viewer,
)
from endopipe.stages.report.kit import video as video_html
from endopipe.stages.report.load import STAGES, CaseData
from endopipe.stages.report.mesh3d import (
    decimate,
    mesh_viewer_page,
    principal_axes,
    render_mesh_view,
    shown_colours,
)

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
    ("coverage", "Coverage", True),
)
#: Protocol blocks of the depth stage's metrics.json (stages.metrics.depth).
DEPTH_PROTOCOLS = (
    ("median_scaled", "per-frame median scaling"),
    ("sequence_scaled", "one scale for the sequence"),
    ("affine_invariant", "scale and shift fitted per frame (relative ground truth)"),
)
GT_BADGES = {
    "exact": ("exact", "ok"),
    "pseudo": ("pseudo", "warn"),
    "none": ("none", "muted"),
}


def _number(value: Any) -> float | None:
    ok = isinstance(value, int | float) and not isinstance(value, bool)
    return float(value) if ok else None


def image_metric(data: CaseData, key: str) -> float | None:
    """PSNR / SSIM of held-out frames: the depth stage's (heldout_psnr, heldout_ssim), else
    the NeRF stage's (psnr)."""
    value = _number((data.depth_metrics or {}).get(f"heldout_{key}"))
    if value is None:
        value = _number((data.nerf_metrics or {}).get(key))
    return value


# --- summary ----------------------------------------------------------------------------------


def section_summary(data: CaseData, info: Any) -> str:
    ing, pos = data.summary("ingest"), data.summary("poses")
    ingest, poses = data.ingest, data.poses
    n_frames = (len(ingest.frames) if ingest is not None else 0) or ing.get("kept")
    registered = total = None
    if poses is not None:
        total = len(poses.file.frames)
        registered = len(poses.registered)
    elif pos:
        registered, total = pos.get("registered"), pos.get("total")
    metric = poses.metric if poses is not None else pos.get("metric")
    gt = info.gt_kind
    gt_badge = badge(*GT_BADGES.get(gt, (gt, "muted")))

    cards = []
    src_frames = ing.get("source_frames")
    cards.append(
        card(
            "Frames",
            fmt(n_frames) if n_frames else fmt(None),
            f"of {src_frames:,} in the input" if isinstance(src_frames, int) else "",
        )
    )
    if registered is not None and total:
        share = f"{100 * registered / total:.0f}%"
        cards.append(card("Registered", share, f"{registered} of {total} frames"))
    else:
        cards.append(card("Registered", fmt(None), "no poses"))
    if metric is None:
        cards.append(card("Scale", fmt(None), "no poses"))
    else:
        note = (
            "aligned to ground truth"
            if pos.get("aligned_to_gt")
            else ("" if metric else "monocular: up to scale")
        )
        cards.append(card("Scale", "metric (mm)" if metric else "arbitrary", note))
    gt_hint = {"pseudo": "e.g. stereo-derived", "relative": "depth up to scale and shift"}
    cards.append(card("Ground truth", gt_badge, gt_hint.get(gt, "")))
    dm = (data.depth_metrics or {}).get("median_scaled") or {}
    am = (data.depth_metrics or {}).get("affine_invariant") or {}
    if dm.get("abs_rel") is not None:
        cards.append(card("Depth AbsRel", fmt(dm.get("abs_rel")), "per-frame median scaling"))
    elif am.get("abs_rel") is not None:
        cards.append(
            card("Depth AbsRel", fmt(am.get("abs_rel")), "scale and shift fitted (relative GT)")
        )
        cards.append(
            card("Depth rank corr.", fmt(am.get("spearman")), "Spearman ρ vs the relative GT")
        )
    cover = _number(dm.get("coverage", am.get("coverage")))
    if cover is not None:
        cards.append(card("Depth coverage", f"{100 * cover:.0f}%", "of valid ground-truth pixels"))
    mm = data.mesh_metrics or {}
    chamfer, fscore = _number(mm.get("chamfer")), _number(mm.get("fscore"))
    if chamfer is not None:
        cards.append(card("Chamfer", fmt(chamfer, "mm"), "mean of both directions"))
    if fscore is not None:
        tau = _number(mm.get("threshold"))
        note = f"at {tau:.3g} mm" if tau is not None else "fscore"
        cards.append(card("F-score", fmt(fscore), text(note)))
    if pos.get("ate_mm") is not None:
        from_gt = pos.get("source") == "gt"
        note = "poses are the ground truth" if from_gt else "after sim(3) alignment"
        cards.append(card("ATE", fmt(pos.get("ate_mm"), "mm"), note))
    psnr = image_metric(data, "psnr")
    if psnr is not None:
        cards.append(card("PSNR", fmt(psnr, "dB"), "held-out frames"))
    verdict = data.pose_verdict() if poses is not None else None
    if verdict is not None:
        kind = {"ok": "ok", "doubtful": "bad"}.get(verdict.status, "muted")
        n_doubtful = len(verdict.doubtful())
        note = f"{n_doubtful} doubtful frame(s)" if verdict.status != "not assessed" else ""
        cards.append(card("Poses", badge(verdict.status, kind), text(note)))

    case = data.case
    rows = [
        ("Case", text(case.name if case else data.case_dir.name)),
        ("Input", f"<code>{text(case.input)}</code>" if case else fmt(None)),
        ("Input kind", text(case.kind) if case else fmt(None)),
    ]
    if ingest is not None:
        rows.append(("Working resolution", f"{ingest.width} × {ingest.height} px"))
    if ing.get("dropped"):
        dropped = ", ".join(f"{v} {k.replace('_', ' ')}" for k, v in ing["dropped"].items() if v)
        rows.append(("Frames dropped", text(dropped or "none")))
    for warning in ing.get("warnings") or []:  # e.g. ground truth that does not match
        rows.append(("Warning", text(warning)))
    if poses is not None:
        cams = poses.file
        rows.append(
            (
                "Camera",
                text(
                    f"{cams.model} {cams.width}×{cams.height}, fx {cams.fx:.1f}, fy {cams.fy:.1f}, "
                    f"cx {cams.cx:.1f}, cy {cams.cy:.1f} px"
                ),
            )
        )
        rows.append(("Pose source", text(cams.source)))
        rows.append(("Units", text(data.units)))
    gt_dir = data.gt_dir()
    gt_note = text(gt_dir) if gt_dir else "none"
    if gt != "none":
        ds = getattr(data.ground_truth(), "dataset", "")
        gt_note = f"{gt_badge} {text(ds)} <code>{gt_note}</code>"
    rows.append(("Ground truth", gt_note))
    honesty = ""
    if gt == "pseudo":
        honesty = (
            '<p class="note">Ground truth is <b>pseudo</b> (not measured): treat metrics as '
            "agreement with another estimate, not as accuracy.</p>"
        )
    elif gt == "none":
        honesty = (
            '<p class="note">No ground truth: the page shows estimates and internal '
            "consistency only; no accuracy is claimed.</p>"
        )
    if verdict is not None and verdict.status == "doubtful":
        honesty += pv.headline_html(verdict)  # the poses section says why, frame by frame
    honesty += "".join(
        f'<p class="verdict"><b>{text(s)}</b></p>' for s in verdicts(data.depth_metrics or {})
    )
    return f'<div class="cards">{"".join(cards)}</div>{honesty}{kv_table(rows)}'


# --- stages -----------------------------------------------------------------------------------


def section_stages(data: CaseData, info: Any) -> str | None:
    walls = [m.wall_s for m in data.manifests.values() if m is not None]
    if not walls and not any(data.folder(s) for s in STAGES):
        return None
    longest = max(walls) if walls else 1.0
    rows: list[dict[str, Any]] = []
    for stage in STAGES:
        m = data.manifests.get(stage)
        folder = data.folder(stage)
        row: dict[str, Any] = {
            "stage": stage,
            "folder": folder.name if folder is not None else None,
            "manifest": m is not None,
        }
        if m is not None:
            row.update(
                wall=duration(m.wall_s),
                share=100.0 * m.wall_s / longest if longest > 0 else 0.0,
                peak_mb=m.peak_rss_mb,
                files=len(m.files),
                size_mb=sum(f.size for f in m.files.values()) / 2**20,
                version=m.version,
                key=m.key[:8],
                finished=dt.datetime.fromtimestamp(m.finished).strftime("%Y-%m-%d %H:%M:%S"),
            )
        rows.append(row)
    peak = max((m.peak_rss_mb for m in data.manifests.values() if m is not None), default=0.0)
    table = stages_table(rows, duration(sum(walls)), peak)
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


# --- input ------------------------------------------------------------------------------------


def section_input(data: CaseData, info: Any) -> str | None:
    ing = data.summary("ingest")
    parts = []
    if data.ingest is not None:
        uri = file_image_uri(data.ingest.contact_sheet_path, 1100, "jpg", data.cfg.jpeg_quality)
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
            ("Field of view", text(ing.get("fov_shape", "—"))),
            ("Field-of-view fraction", fmt(ing.get("fov_fraction"))),
            ("Mean specular fraction", fmt(ing.get("mean_specular_fraction"))),
        ]
        parts.append(kv_table(rows))
    return "".join(parts) if parts else None


# --- poses and centre line --------------------------------------------------------------------


def gt_centres(data: CaseData, ids: list[int]) -> np.ndarray | None:
    """Ground-truth camera centres of the registered frames, when poses are in the GT frame."""
    from endopipe.stages.io.ground_truth import poses_by_frame

    if data.poses is None or not data.poses.metric or data.ingest is None:
        return None
    truth = poses_by_frame(data.ground_truth(), data.ingest.frames)
    if truth is None or any(i not in truth for i in ids):
        return None
    return np.reshape([truth[i][:3, 3] for i in ids], (-1, 3))


def centre_line(data: CaseData) -> Curve | None:
    cl = data.centerline
    if cl is None:
        return None
    return Curve(cl.points, cl.radius, cl.arclength, cl.file.camera_span)


def unregistered_frames(poses: Any) -> str:
    """Frames without a pose, as ranges: '4, 9-11'."""
    runs: list[str] = []
    for i in (f.index for f in poses.file.frames if not f.registered):
        if runs and runs[-1].split("-")[-1] == str(i - 1):
            runs[-1] = f"{runs[-1].split('-')[0]}-{i}"
        else:
            runs.append(str(i))
    return ", ".join(runs) or "none"


def section_poses(data: CaseData, info: Any) -> str | None:
    parts = []
    poses = data.poses
    if poses is not None:
        verdict = data.pose_verdict()
        parts.append(pv.verdict_block(verdict, data.verdict_error))
        ids = poses.registered
        if ids:
            centres = poses.centres()
            views = np.reshape([poses.c2w[i][:3, 2] for i in ids], (-1, 3))
            try:
                gt = gt_centres(data, ids)
            except Exception:  # noqa: BLE001 - GT overlay is optional
                gt = None
            flagged = {f.index for f in verdict.doubtful()} if verdict is not None else set()
            doubtful = np.array([i in flagged for i in ids]) if flagged else None
            uri = plot_trajectory(centres, views, centre_line(data), gt, data.units, doubtful)
            caption = (
                "Camera centres (coloured by frame order, arrows: viewing direction) and the "
                "lumen centre line with its radius"
                + ("; dashed: ground-truth trajectory" if gt is not None else "")
                + ("; red crosses: doubtful poses" if doubtful is not None else "")
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
            ("Pose source", text(pos.get("source", "—"))),
            (
                "Registered",
                f"{fmt(pos.get('registered'))} of {fmt(pos.get('total'))} "
                f"({fmt(100 * pos.get('registered_fraction', 0.0))}%)",
            ),
            (
                "Unregistered frames",
                text(unregistered_frames(poses) if poses else pos.get("unregistered") or "none"),
            ),
            ("Camera model", text(pos.get("camera_model", "—"))),
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
        kind = str(cl.get("kind", "—"))
        rows += [
            ("Lumen prior", text({"none": "none (no anatomical prior)"}.get(kind, kind))),
            ("Why", text(cl.get("prior_reason") or "—")),
            ("L_prior weight", fmt(cl.get("prior_weight"))),
            ("Rays reach", fmt(cl.get("reach"), u)),
        ]
        if kind != "none":
            if cl.get("wall_margin"):
                margin = float(cl["wall_margin"])
                reach_wall = f"{1 + margin:.2f}x the wall (centerline.reach_share)"
                rows.append(("Most SfM points lie within", text(reach_wall)))
            if cl.get("core_limit") is not None and float(cl["core_limit"]) < 1.0:
                core = f"{float(cl['core_limit']):.2f} of the wall (centerline.core_share)"
                rows.append(("Empty core at most", text(core)))
            rows += [
                ("Centre line length", fmt(cl.get("length"), u)),
                ("Mean radius", fmt(cl.get("mean_radius"), u)),
                ("Radius from", fmt(cl.get("radius_note") or cl.get("radius_source"))),
            ]
        else:
            rows.append(("Scene unit", fmt(cl.get("mean_radius"), u)))
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
    if data.centerline is not None:
        uri = file_image_uri(data.centerline.plot_path, 1100)
        if uri:
            parts.append(
                "<details><summary>Centre line stage's own diagnostic plot</summary>"
                + figure_html(uri, "03_centerline/centerline.png", "wide")
                + "</details>"
            )
    if poses is None and not rows:
        return None
    return "".join(parts)


# --- nerf -------------------------------------------------------------------------------------


def section_nerf(data: CaseData, info: Any) -> str | None:
    parts = []
    nerf = data.nerf
    loss = file_image_uri(nerf.loss_plot_path, 1100) if nerf is not None else None
    if loss is not None:
        parts.append(figure_html(loss, "Training losses (log scale) and training PSNR.", "wide"))
    else:
        parts.append(not_available("no loss curves (04_nerf/loss.png)"))
    held = None
    if nerf is not None:
        held = file_image_uri(nerf.heldout_plot_path, 1100, "jpg", data.cfg.jpeg_quality)
    if held is not None:
        parts.append(
            figure_html(
                held,
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
            (
                "Field render time, depth only",
                fmt(s.get("render_ms"), "ms") + " per held-out frame",
            ),
            ("Device", text(s.get("device", "—"))),
        ]
        if s.get("resumed_from"):
            rows.append(("Resumed from step", fmt(s.get("resumed_from"))))
    nm = data.nerf_metrics or {}
    if nm.get("render_rgb_ms") is not None:
        rows.append(
            (
                "Field render time, colour and depth",
                fmt(nm.get("render_rgb_ms"), "ms") + " per held-out frame",
            )
        )
    if nm.get("psnr") is not None or s.get("heldout_psnr") is not None:
        rows.append(("Held-out PSNR", fmt(nm.get("psnr", s.get("heldout_psnr")), "dB")))
    if rows:
        parts.append(kv_table(rows))
        parts.append(
            '<p class="note">Render times: one full frame rendered by the trained field (ray '
            "marching), timed on the held-out frames. The depth stage renders every frame again, "
            "with its own renderer and time (Depth section).</p>"
        )
    if isinstance(nm.get("depth"), dict):
        parts.append(
            "<h3>Rendered depth on held-out frames</h3>"
            + depth_metric_table(nm["depth"], data.units)
        )
    if loss is None and held is None and not s:
        return None
    return "".join(parts)


# --- depth ------------------------------------------------------------------------------------


def depth_metric_table(metrics: dict, units: str = "") -> str:
    """The protocols side by side; a metric missing from one protocol shows '—'."""
    protos = [(k, label) for k, label in DEPTH_PROTOCOLS if isinstance(metrics.get(k), dict)]
    if not protos:
        return not_available("no depth metrics")
    keys = [m for m in DEPTH_METRICS if any(m[0] in metrics[p] for p, _ in protos)]
    known = {m[0] for m in DEPTH_METRICS}
    extra = sorted(
        {
            k
            for p, _ in protos
            for k, v in metrics[p].items()
            if k not in known and _number(v) is not None
        }
    )
    rows = []
    for key, label, higher in keys:
        arrow = "↑" if higher else "↓"
        unit = units if key == "rmse" else ""
        head = f'{label} <span class="muted">{arrow}</span>'
        rows.append([head, *(fmt(metrics[p].get(key), unit) for p, _ in protos)])
    for key in extra:
        rows.append([text(key), *(fmt(metrics[p].get(key)) for p, _ in protos)])
    cols = tuple(range(len(protos)))
    return grid([label for _, label in protos], rows, "grid metrics", num=cols, row_head=True)


def per_frame_series(per_frame: Any, metric: str = "abs_rel") -> dict[str, tuple[list, list]]:
    """`metric` per frame, by protocol, from metrics.json's per_frame list: entries carry
    "index" and a block per protocol (or, for a relative ground truth, the metrics flat)."""
    out: dict[str, tuple[list, list]] = {}
    if not isinstance(per_frame, list):
        return out
    frames = [f for f in per_frame if isinstance(f, dict)]
    for proto, label in DEPTH_PROTOCOLS:
        pts = [
            (f.get("index", i), f[proto][metric])
            for i, f in enumerate(frames)
            if isinstance(f.get(proto), dict) and f[proto].get(metric) is not None
        ]
        if pts:
            out[label] = ([p[0] for p in pts], [p[1] for p in pts])
    if not out:
        pts = [
            (f.get("index", i), f[metric])
            for i, f in enumerate(frames)
            if f.get(metric) is not None
        ]
        if pts:
            out["per frame"] = ([p[0] for p in pts], [p[1] for p in pts])
    return out


def pick_frames(indices: list[int], count: int) -> list[int]:
    if count <= 0 or not indices:
        return []
    if len(indices) <= count:
        return list(indices)
    pos = np.linspace(0, len(indices) - 1, count).round().astype(int)
    return [indices[p] for p in dict.fromkeys(pos.tolist())]


def preview_row(data: CaseData, index: int) -> PreviewRow:
    """Frame `index`: image, depth (median-scaled to the truth when there is one), truth, and
    the abs-rel error on pixels the frame's mask keeps."""
    from endopipe.stages.depth.preview import scaled_error
    from endopipe.stages.io.ground_truth import depth_of_frame

    depth = np.asarray(data.depth.depth(index), np.float32)
    h, w = depth.shape[:2]
    ingest = data.ingest
    rgb = mask = entry = None
    if ingest is not None and ingest.has_frame(index):
        entry = ingest.frame(index)
        img = ingest.image(index)
        rgb = cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)
        m = ingest.mask(index)
        if m is not None:
            mask = cv2.resize(m, (w, h), interpolation=cv2.INTER_NEAREST) > 127
    src = entry.source_index if entry is not None else None
    gt_depth = error = scale = None
    g = depth_of_frame(data.ground_truth(), entry) if entry is not None else None
    if g is not None:
        g = np.asarray(g, dtype=np.float32)
        if g.shape != depth.shape:
            g = cv2.resize(g, (w, h), interpolation=cv2.INTER_NEAREST)
        gt_depth = g
        valid = (g > 0) & (depth > 0) & np.isfinite(depth)
        if mask is not None:
            valid &= mask
        if valid.sum() > 10:
            error, scale, _ = scaled_error(depth, g, valid)
    shown = depth * scale if scale is not None else depth
    return PreviewRow(index, src, rgb, shown, gt_depth, error, scale, mask)


def _shrink_row(row: PreviewRow, width: int) -> PreviewRow:
    h, w = row.depth.shape[:2]
    size = (width, max(1, round(h * width / w)))

    def near(a: np.ndarray | None) -> np.ndarray | None:
        return None if a is None else cv2.resize(a, size, interpolation=cv2.INTER_NEAREST)

    rgb = None if row.rgb is None else cv2.resize(row.rgb, size, interpolation=cv2.INTER_AREA)
    inside = None if row.inside is None else near(row.inside.astype(np.uint8)) > 0
    return PreviewRow(
        row.index,
        row.source_index,
        rgb,
        near(row.depth),
        near(row.gt),
        near(row.error),
        row.scale,
        inside,
    )


def depth_previews(data: CaseData) -> str:
    cfg = data.cfg
    picks = pick_frames(sorted(data.depth.indices), cfg.max_preview_frames)
    if not picks:
        return not_available("no depth maps in 05_depth/depth/")
    rows, bad = [], []
    for i in picks:
        try:
            row = preview_row(data, i)
        except Exception as e:  # noqa: BLE001 - one unreadable map costs one row
            bad.append(f"frame {i}: {one_line(e)}")
            continue
        if row.depth.ndim != 2:
            bad.append(f"frame {i}: depth map of shape {row.depth.shape}")
            continue
        rows.append(row)
    note = not_available("; ".join(bad)) if bad else ""
    if not rows:
        return note
    rows = [r for r in rows if r.depth.shape == rows[0].depth.shape]
    if cfg.preview_width and rows[0].depth.shape[1] > cfg.preview_width:
        rows = [_shrink_row(r, cfg.preview_width) for r in rows]
    uri = plot_depth_preview(rows, data.units, cfg.error_max)
    cap = "Depth previews: RGB | depth (turbo colour map, near = blue; grey = no depth)"
    has_gt = any(r.gt is not None for r in rows)
    if has_gt:  # four columns
        cap += (
            " | ground truth (same colour scale) | abs-rel error after per-frame median "
            f"scaling (0 to {cfg.error_max:g}; grey = ground truth but no depth)"
        )
    return figure_html(uri, cap + ".", "wide" if has_gt else "medium") + note


RENDERERS = {
    "baked": "the surface baked from the field once, then ray cast",
    "field": "the field itself, ray marched",
}


def depth_render_rows(data: CaseData) -> str:
    """How the depth stage rendered its maps, and what a frame cost (beside the NeRF's time)."""
    s = data.summary("depth")
    if not s:
        return ""
    renderer = str(s.get("renderer", ""))
    how = f"{renderer}: {RENDERERS[renderer]}" if renderer in RENDERERS else renderer
    rows = [
        ("Depth maps", f"{fmt(s.get('frames'))} (every registered frame)"),
        ("Renderer", text(how)),
        ("Depth stage render time", fmt(s.get("ms_per_frame"), "ms") + " per frame (median)"),
    ]
    if renderer == "baked" and _number(s.get("bake_s")) is not None:
        rows.append(("Baking the surface", fmt(s.get("bake_s"), "s") + " once"))
    unknown, hazy = _number(s.get("unknown_share")), _number(s.get("hazy_share"))
    if unknown is not None:
        why = "their rays found no surface"
        if hazy:
            why = f"{100 * hazy:.1f}% spread over no one surface, depth.max_spread"
            if unknown - hazy > 5e-4:
                why += "; the rest found none"
        rows.append(("No depth (unknown)", f"{100 * unknown:.1f}% of the lens's pixels ({why})"))
    return "<h3>Rendering</h3>" + kv_table(rows)


def section_depth(data: CaseData, info: Any) -> str | None:
    if data.depth is None:
        if "depth" in data.view_errors:
            return not_available(f"05_depth unreadable: {data.view_errors['depth']}")
        return None
    parts = []
    dm = data.depth_metrics
    if dm is not None:
        parts.append(
            '<h3>Depth accuracy</h3><p class="note">Per frame, on pixels with valid ground '
            "truth, averaged over frames. <b>Per-frame median scaling</b> is the standard "
            "monocular protocol (Monodepth2 / Endo-SfM); <b>one scale for the sequence</b> is "
            "stricter and rewards a 3D-consistent reconstruction. <b>Coverage</b> is the share "
            "of those pixels that got a depth; every other metric is computed on the covered "
            "pixels only.</p>"
        )
        parts.append(depth_metric_table(dm, data.units))
        parts.append(comparison(dm))
        if isinstance(dm.get("frames"), int):
            parts.append(f'<p class="note">{dm["frames"]} frame(s) evaluated.</p>')
        img_rows = []
        for key, label, unit in (("psnr", "PSNR", "dB"), ("ssim", "SSIM", "")):
            value = image_metric(data, key)
            img_rows.append((label, fmt(value, unit) if value is not None else "not available"))
        held = dm.get("heldout_frames")
        if isinstance(held, list):
            img_rows.append(("Held-out frames", text(", ".join(map(str, held)) or "none")))
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

    parts.append(depth_render_rows(data))
    parts.append("<h3>Previews</h3>" + depth_previews(data))

    preview = data.depth.preview_path
    if preview.is_file() and data.cfg.include_video:
        size_mb = preview.stat().st_size / 2**20
        if size_mb <= data.cfg.max_video_mb:
            note = (
                "05_depth/preview.mp4, every registered frame: image | estimated depth (turbo, "
                "one scale for the video) | abs-rel error after per-frame median scaling "
                "(inferno, the colour maps of the previews above)."
            )
            parts.append("<h3>Preview video</h3>" + video_html(video_uri(preview), note))
        else:
            parts.append(
                "<h3>Preview video</h3>"
                + not_available(
                    f"preview.mp4 is {size_mb:.1f} MB (over max_video_mb = "
                    f"{data.cfg.max_video_mb:g}); open it next to the report: {preview}"
                )
            )
    return "".join(parts)


# --- mesh -------------------------------------------------------------------------------------


Row = tuple[str, str, str]  # label, value (HTML), note (HTML)

#: metrics.json / summary keys the mesh table shows in its own rows (anything else numeric is
#: listed under "other values", so nothing the stage wrote is dropped without a word).
MESH_SHOWN = {
    "evaluated", "reason", "gt_kind", "chamfer", "chamfer_pct_radius", "accuracy",
    "completeness", "accuracy_median", "completeness_median", "precision", "recall", "fscore",
    "threshold", "gt_area_seen", "gt_points", "est_points", "by_camera_distance", "aligned",
    "sim3_scale", "mean_radius", "crop_max_depth", "crop", "eval_s", "method", "vertices",
    "faces", "raw_vertices", "raw_faces", "voxel_size", "sdf_trunc", "depth_trunc",
    "frames_used", "level", "band_nodes", "faces_extracted", "seen_fraction",
    "components_removed", "units", "build_s", "clean_s", "off_seen_pct", "off_seen_threshold",
}  # fmt: skip
METHODS = {
    "tsdf": "TSDF fusion of the depth maps",
    "marching_cubes": "marching cubes on the NeRF's density",
}


def _count(value: Any) -> str:
    number = _number(value)
    return fmt(int(number)) if number is not None else fmt(None)


def mesh_accuracy_rows(m: dict, u: str) -> list[Row]:
    """The comparison with the ground-truth surface, in the truth's units `u`."""
    tau = _number(m.get("threshold"))
    at = f"{tau:g} {u}" if tau is not None else "the threshold"
    pct = _number(m.get("chamfer_pct_radius"))
    rows = [
        (
            "Chamfer distance",
            fmt(_number(m.get("chamfer")), u),
            "mean of accuracy and completeness"
            + (f"; {fmt(pct, '%')} of the lumen radius" if pct is not None else ""),
        ),
        (
            "Accuracy",
            fmt(_number(m.get("accuracy")), u),
            f"mean distance, estimate → truth (median {fmt(_number(m.get('accuracy_median')), u)})",
        ),
        (
            "Completeness",
            fmt(_number(m.get("completeness")), u),
            "mean distance, truth → estimate "
            f"(median {fmt(_number(m.get('completeness_median')), u)})",
        ),
        ("F-score", fmt(_number(m.get("fscore"))), f"at {text(at)}"),
        ("Precision", fmt(_number(m.get("precision"))), f"share of the estimate within {text(at)}"),
        ("Recall", fmt(_number(m.get("recall"))), f"share of the truth within {text(at)}"),
        (
            "Off the seen surface",
            fmt(_number(m.get("off_seen_pct")), "%"),
            "share of the estimate farther than "
            f"{fmt(_number(m.get('off_seen_threshold')), u)} from any true surface a camera saw "
            "(made up or misplaced)",
        ),
    ]
    keys = ("chamfer", "accuracy", "completeness", "fscore", "precision", "recall", "off_seen_pct")
    if not m.get("evaluated"):
        return []
    return [row for row, key in zip(rows, keys, strict=True) if _number(m.get(key)) is not None]


def mesh_evaluation_rows(m: dict, u: str) -> list[Row]:
    """How the comparison was made: alignment, region, samples, time."""
    if not m.get("evaluated"):
        return []
    aligned = str(m.get("aligned") or "")
    how = {
        "gt_frame": ("none", "the poses are already in the ground truth's frame"),
        "sim3": (
            f"sim(3), scale {fmt(_number(m.get('sim3_scale')))}",
            "similarity transform of the trajectory onto the truth's (Umeyama)",
        ),
    }.get(aligned, (text(aligned or "—"), ""))
    rows = [("Alignment", how[0], how[1])]
    if m.get("crop"):
        crop = text(m["crop"]).replace("gt surface", "ground-truth surface")
        crop = crop.replace(" within crop_max_depth", "")
        rows.append(
            (
                "Region compared",
                fmt(_number(m.get("crop_max_depth")), u),
                f"{crop}, up to this depth",
            )
        )
    if _number(m.get("gt_area_seen")) is not None:
        rows.append(("Truth surface compared", fmt(m["gt_area_seen"], f"{u}²"), "area"))
    if m.get("gt_points") is not None:
        rows.append(
            (
                "Points sampled",
                f"{_count(m.get('est_points'))} / {_count(m.get('gt_points'))}",
                "on the estimate / on the truth",
            )
        )
    if _number(m.get("mean_radius")) is not None:
        rows.append(("Lumen radius", fmt(m["mean_radius"], u), "the truth's mean: the % above"))
    if _number(m.get("eval_s")) is not None:
        rows.append(("Evaluation time", fmt(m["eval_s"], "s"), ""))
    return rows


def mesh_build_rows(m: dict, summary: dict, units: str) -> list[Row]:
    """The surface itself: method, size after clean-up (what mesh.ply holds), parameters."""
    rows: list[Row] = []
    method = str(m.get("method") or summary.get("method") or "")
    if method:
        rows.append(("Method", text(method), text(METHODS.get(method, ""))))
    vertices = m.get("vertices", summary.get("vertices"))
    faces = m.get("faces", summary.get("faces"))
    if vertices is not None:
        before = (
            f"before clean-up {_count(m['raw_vertices'])} vertices, {_count(m.get('raw_faces'))}"
            " faces"
            if m.get("raw_vertices") is not None
            else ""
        )
        rows.append(("Vertices", _count(vertices), "in mesh.ply, after clean-up"))
        rows.append(("Faces", _count(faces), before))
    if m.get("components_removed") is not None:
        rows.append(("Clean-up", _count(m["components_removed"]), "small components removed"))
    for key, label, note in (
        ("voxel_size", "Voxel size", ""),
        ("sdf_trunc", "SDF truncation", ""),
        ("depth_trunc", "Depth truncation", "depth beyond this is not fused"),
    ):
        if _number(m.get(key, summary.get(key))) is not None:
            rows.append((label, fmt(float(m.get(key, summary.get(key))), units), note))
    if m.get("frames_used", summary.get("frames_used")) is not None:
        rows.append(("Frames used", _count(m.get("frames_used", summary.get("frames_used"))), ""))
    for key, label in (("build_s", "Build time"), ("clean_s", "Clean-up time")):
        if _number(summary.get(key)) is not None:
            rows.append((label, fmt(summary[key], "s"), ""))
    return rows


def mesh_other_rows(m: dict) -> list[Row]:
    """Numbers in metrics.json that the table has no row for, under their own key."""
    return [
        (key.replace("_", " "), fmt(v), f"<code>{text(key)}</code>")
        for key, v in m.items()
        if key not in MESH_SHOWN and (_number(v) is not None or isinstance(v, str))
    ]


def mesh_table(data: CaseData) -> str:
    """The mesh's numbers in one table: accuracy, how it was evaluated, the surface."""
    m = data.mesh_metrics or {}
    summary = data.summary("mesh")
    gt_units = str(getattr(data.ground_truth(), "units", "") or "mm") if m.get("evaluated") else ""
    units = str(summary.get("units") or data.units)
    return grouped_table(
        [
            (f"Accuracy against the ground truth ({gt_units})", mesh_accuracy_rows(m, gt_units)),
            ("How it was evaluated", mesh_evaluation_rows(m, gt_units)),
            ("The surface (06_mesh/mesh.ply)", mesh_build_rows(m, summary, units)),
            ("Other values in metrics.json", mesh_other_rows(m)),
        ]
    )


def distance_band_table(bands: Any, radius: Any, units: str) -> str:
    """metrics.json's by_camera_distance as a table: where the mesh can be trusted."""
    if not isinstance(bands, list) or not bands:
        return ""

    def edge(v: Any) -> str:
        if v is None:
            return "∞"
        return f"{v / radius:.1f}" if isinstance(radius, int | float) and radius > 0 else fmt(v)

    rows = [
        [
            f"{edge(b.get('from'))}–{edge(b.get('to'))}",
            fmt(b.get("chamfer"), units),
            fmt(b.get("chamfer_pct_radius"), "%"),
            fmt(b.get("accuracy"), units),
            fmt(b.get("completeness"), units),
            fmt(100.0 * b["gt_share"], "%") if isinstance(b.get("gt_share"), float) else "—",
        ]
        for b in bands
        if isinstance(b, dict)
    ]
    head = [
        "nearest camera (radii)",
        "Chamfer",
        "% of radius",
        "accuracy",
        "completeness",
        "share of GT surface",
    ]
    return (
        '<p class="note">By distance of the surface to the nearest camera centre: depth error '
        "grows with distance, so the surface the scope passed close to is the part to trust.</p>"
        + grid(head, rows, "grid metrics", num=tuple(range(len(head))))
    )


def section_mesh(data: CaseData, info: Any) -> str | None:
    if data.mesh is None:
        if "mesh" in data.view_errors:
            info.mesh_viewer = "none"
            return not_available(f"06_mesh unreadable: {data.view_errors['mesh']}")
        return None
    parts = ["<h3>Surface accuracy</h3>"]
    mm = data.mesh_metrics
    if mm and mm.get("evaluated") is False:
        parts.append(not_available(f"not evaluated: {mm.get('reason') or 'no reason given'}"))
    elif mm:
        parts.append(
            '<p class="note">The estimated surface against the ground-truth surface that the '
            "cameras saw, in the ground truth's units.</p>"
        )
    else:
        reason = (
            "no ground-truth surface to compare with"
            if info.gt_kind == "none"
            else "06_mesh/metrics.json is missing"
        )
        parts.append(not_available(reason))
    parts.append(mesh_table(data))
    if mm and mm.get("evaluated"):
        gt_units = str(getattr(data.ground_truth(), "units", "") or "mm")
        parts.append(
            distance_band_table(mm.get("by_camera_distance"), mm.get("mean_radius"), gt_units)
        )
    parts.append(mesh_views(data, info))
    return "".join(parts)


def mesh_views(data: CaseData, info: Any) -> str:
    """The 3D viewer and the static renderings of 06_mesh's mesh, decimated to the budget."""
    cfg = data.cfg
    if not data.mesh.mesh_path.is_file():
        info.mesh_viewer = "none"
        return "<h3>3D view</h3>" + not_available("06_mesh/mesh.ply is missing")
    try:
        raw = data.mesh.load()
        if len(raw.faces) == 0:
            raise ValueError("mesh.ply holds no triangles")
        colours = shown_colours(raw.colours, len(raw.vertices))
        v, f, c = decimate(raw.vertices, raw.faces, cfg.mesh_max_faces, colours)
    except Exception as e:  # noqa: BLE001
        return "<h3>3D view</h3>" + not_available(f"mesh.ply unreadable: {one_line(e)}")
    n_orig = len(raw.faces)
    note = (
        f"{n_orig:,} faces, shown decimated to {len(f):,}"
        if len(f) < n_orig
        else f"{n_orig:,} faces"
    )
    viewer_html = ""
    info.mesh_viewer = "static"
    if cfg.include_mesh_viewer:
        path_points = data.poses.centres() if data.poses is not None else None
        try:
            page = mesh_viewer_page(v, f, c, path_points)
            viewer_html = viewer(
                page,
                "Interactive: drag to rotate, scroll to zoom, right-drag to pan. three.js is "
                "inlined (bundled with trimesh), so this works offline; it needs WebGL. "
                "Blue line: camera path.",
            )
            info.mesh_viewer = "three.js (inlined from trimesh)"
        except Exception as e:  # noqa: BLE001 - fall back to the static views
            viewer_html = not_available(
                f"interactive viewer: {one_line(e)}; static views below instead"
            )
    views = []
    if cfg.mesh_views:
        axes = principal_axes(v)
        defs = [
            ("side", axes[0], axes[1]),
            ("top", axes[0], axes[2]),
            ("end-on (along the lumen)", axes[1], axes[2]),
        ][: cfg.mesh_views]
        for label, right, up in defs:
            img = render_mesh_view(v, f, c, right, up)
            views.append(figure_html(image_uri(img, "jpg", cfg.jpeg_quality), label))
    return (
        f'<h3>3D view</h3><p class="note">06_mesh/mesh.ply: {text(note)}.</p>'
        + viewer_html
        + (f'<div class="views">{"".join(views)}</div>' if views else "")
        + (
            '<p class="note">Static orthographic views along the mesh\'s principal axes.</p>'
            if views
            else ""
        )
    )


# --- runs -------------------------------------------------------------------------------------


def run_state(record: Any) -> str:
    """The run's result as a badge. A record without an end is the run writing this page (its
    process is alive), or a run whose process died before it could record its end."""
    if record.finished is not None:
        return badge("ok", "ok") if record.ok else badge("failed", "bad")
    if record.pid == os.getpid() and record.host == platform.node():
        return badge("this run, in progress", "warn")
    if record.host == platform.node() and record.pid and psutil.pid_exists(record.pid):
        return badge(f"in progress (pid {record.pid})", "warn")
    return badge("no end recorded (killed?)", "bad")


def run_row(record: Any) -> list[str]:
    """One run: started, result, wall time, what ran, what came from the cache."""
    ran = ", ".join(s.stage for s in record.stages if s.status == "ran") or "—"
    cached = ", ".join(s.stage for s in record.stages if s.status == "cached") or "—"
    failed = [s for s in record.stages if s.status == "failed"]
    why = text(failed[0].reason) if failed else ""
    if record.finished is None:
        done = len(record.stages)
        why = text(f"{done} stage(s) done so far" if done else "no stage done yet")
    wall = duration(record.wall_s) + (" so far" if record.finished is None else "")
    return [text(record.started), f"{run_state(record)} {why}", wall, text(ran), text(cached)]


def section_runs(data: CaseData, info: Any) -> str | None:
    from endopipe.pipeline.runner import package_versions

    parts = []
    records = data.runs
    if records:
        rows = [run_row(r) for r in records]
        parts.append(grid(["started", "result", "wall time", "ran", "cached"], rows, num=(2,)))
        if records[0].finished is None:
            parts.append(
                '<p class="note">The newest run was still going when this page was written: '
                "it lists the stages done before the report stage.</p>"
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
                ("Host", text(host)),
                ("Python", text(python)),
                ("Packages", text(env) or "—"),
            ]
        )
    )
    return "".join(parts)
