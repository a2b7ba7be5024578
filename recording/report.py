"""recording/report.html: the recording on one self-contained page, with the report stage's
kit (templates, styles): a timeline of every frame (kept, dropped by reason, registered or not)
under the windows and their junctions, the windows' table with links to their own reports, the
joined trajectory against the truth, and the scores."""

from __future__ import annotations

import datetime as dt
from pathlib import Path

import numpy as np
from markupsafe import Markup, escape

from endopipe.recording.frames import FramePose
from endopipe.recording.join import Joined
from endopipe.recording.summary import RecordingSummary, light_line
from endopipe.recording.windows import WindowPlan

REASON_COLOURS = {
    "kept": "#2e7d32",
    "little_motion": "#c8e6c9",
    "still": "#90a4ae",
    "blurred": "#ef6c00",
    "washed_out": "#fdd835",
    "blank": "#000000",
    "duplicate": "#b0bec5",
}


def _img(fig) -> Markup:
    """A figure as an inline image (the report stage's encoding)."""
    from endopipe.stages.report.figures import figure_uri

    fig.tight_layout()
    return Markup(f'<img src="{figure_uri(fig)}" style="max-width:100%">')


def timeline(
    kept: list[int],
    dropped: dict[str, list[int]],
    plan: WindowPlan,
    joined: Joined,
    frames: list[FramePose] | None,
) -> Markup:
    """Frames along x: what ingest did with each, the windows, and which frames got a pose."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, 2.6), dpi=110)
    ax = fig.subplots()
    rows = {"kept": kept, **dropped}
    for reason, idx in rows.items():
        if idx:
            ax.vlines(
                idx, 2.6, 3.4, color=REASON_COLOURS.get(reason, "#7b1fa2"), lw=1, label=reason
            )
    errors = {j.b: j for j in joined.junctions}
    for k, w in enumerate(plan.windows):
        name = plan.name(k)
        y = 1.5 + 0.35 * (k % 2)
        colour = "#1565c0" if name in joined.windows else "#c62828"
        ax.plot([w[0], w[-1]], [y, y], color=colour, lw=5, solid_capstyle="butt")
        j = errors.get(name)
        label = name if j is None or j.error_pct is None else f"{name} ({j.error_pct:.2f}%)"
        ax.text(w[0], y + 0.18, label, fontsize=7)
    if frames:
        posed = [f.source_index for f in frames if f.c2w is not None]
        lost = [f.source_index for f in frames if f.c2w is None]
        ax.vlines(posed, 0.3, 0.9, color="#1565c0", lw=0.6, label="posed")
        ax.vlines(lost, 0.3, 0.9, color="#c62828", lw=1, label="no pose")
        doubt = [f.source_index for f in frames if f.doubt]
        if doubt:
            ax.vlines(doubt, 0.2, 1.0, color="#ef6c00", lw=1.5, label="keyframe doubtful")
    ax.set_yticks([0.6, 1.7, 3.0], ["frames posed", "windows", "ingest"])
    ax.set_xlabel("frame of the input")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.35), ncol=8, fontsize=7, frameon=False)
    ax.set_ylim(0, 3.8)
    return _img(fig)


def unposed(frames: list[FramePose] | None, most: int = 30) -> Markup:
    """The runs of frames left without a pose and depth, each with why (its first frame's
    reason, and ingest's for not keeping it)."""
    if not frames:
        return Markup("<p class='muted'>Frames were not posed one by one (no depth maps yet).</p>")
    runs: list[list[FramePose]] = []
    for f in frames:
        if f.c2w is not None:
            continue
        if runs and runs[-1][-1].source_index == f.source_index - 1:
            runs[-1].append(f)
        else:
            runs.append([f])
    if not runs:
        return Markup(f"<p>All {len(frames)} frames have a pose and a depth map.</p>")
    rows = "".join(
        f"<tr><td>{r[0].source_index}"
        + (f"-{r[-1].source_index}" if len(r) > 1 else "")
        + f"</td><td>{len(r)}</td><td>{escape(r[0].dropped or 'kept')}</td>"
        f"<td>{escape(r[0].reason or '')}</td></tr>"
        for r in runs[:most]
    )
    more = (
        f"<p class='muted'>and {len(runs) - most} more runs (frames.json)</p>"
        if len(runs) > most
        else ""
    )
    lost = sum(len(r) for r in runs)
    return Markup(
        f"<p>{lost} of {len(frames)} frames have no pose and no depth: unknown, never "
        "interpolated.</p><table><tr><th>frames</th><th>count</th><th>ingest</th>"
        f"<th>why no pose (the first frame's)</th></tr>{rows}</table>{more}"
    )


def trajectory_figure(joined: Joined, truth: list[np.ndarray] | None) -> Markup:
    """The joined camera centres, each coordinate against the path's main axis, with the
    truth aligned onto them (a similarity) where there is one."""
    from matplotlib.figure import Figure

    from endopipe.stages.camera.transforms import umeyama

    segs = [
        np.array([f.c2w for f in joined.frames if f.segment == k])[:, :3, 3]
        for k in range(joined.segments)
    ]
    everything = np.concatenate(segs)
    centre = everything.mean(0)
    _, _, axes = np.linalg.svd(everything - centre)  # along the path first
    fig = Figure(figsize=(10, 4), dpi=110)
    panels = fig.subplots(2, 1, sharex=True)
    for k, c in enumerate(segs):
        q = (c - centre) @ axes.T
        for j, ax in enumerate(panels):
            ax.plot(q[:, 0], q[:, j + 1], ".-", ms=2, lw=0.8, label=f"joined, segment {k}")
    for k in range(joined.segments if truth is not None else 0):
        own = [f for f in joined.frames if f.segment == k and f.source_index < len(truth)]
        if len(own) >= 3:  # each segment against the truth aligned onto it alone
            est = np.array([f.c2w for f in own])[:, :3, 3]
            gt = np.array([truth[f.source_index][:3, 3] for f in own])
            s, r, t = umeyama(gt, est)
            q = (s * gt @ r.T + t - centre) @ axes.T
            for j, ax in enumerate(panels):
                ax.plot(
                    q[:, 0], q[:, j + 1], "k--", lw=0.8, label="truth (aligned)" if k == 0 else None
                )
    for j, ax in enumerate(panels):
        ax.set_ylabel(("across", "up")[j])
    panels[-1].set_xlabel("along the path (the joined trajectory's units)")
    panels[0].legend(fontsize=7)
    return _img(fig)


def scale_figure(joined: Joined, light_text: str) -> Markup:
    """What the light said about the path's scale: the factor each keyframe's lengths were
    multiplied by (1: as joined), along the recording; or why the path is as joined."""
    from matplotlib.figure import Figure

    knots = [k for k in joined.knots if k.segment == 0]
    note = Markup(f"<p class='muted'>{escape(light_text)}</p>")
    if not knots:
        return note
    fig = Figure(figsize=(10, 2.2), dpi=110)
    ax = fig.subplots()
    ax.plot([k.source_index for k in knots], [k.factor for k in knots], lw=1.0)
    ax.axhline(1.0, color="#90a4ae", lw=0.6)
    ax.set_xlabel("frame")
    ax.set_ylabel("length factor")
    return note + _img(fig)


def write_report(
    path: Path,
    name: str,
    summary: RecordingSummary,
    plan: WindowPlan,
    joined: Joined,
    kept: list[int],
    dropped: dict[str, list[int]],
    frames: list[FramePose] | None,
    truth: list[np.ndarray] | None,
    window_pages: dict[str, str],
) -> None:
    """The recording's page: verdict and scores, timeline, windows (each linked to its own
    report, `window_pages`: relative links by window name), trajectory, scale."""
    from endopipe import __version__
    from endopipe.stages.report.kit import fmt, page

    verdict = "ok" if summary.verdict == "ok" else "doubtful"
    reasons = "".join(f"<li>{escape(r)}</li>" for r in summary.reasons)
    relative = summary.depth_gt_kind == "relative"
    absrel = "SSI-AbsRel" if relative else "AbsRel"
    scores = [
        ("keyframes / windows", f"{summary.keyframes} / {len(plan.windows)}"),
        (
            "poses",
            "one SfM over the recording" if summary.one_sfm else "each window's own SfM, joined",
        ),
        ("segments", str(summary.segments)),
        ("ATE, joined trajectory (% of path)", fmt(summary.ate_percent_of_path)),
        (
            "ATE by segment, each aligned on its own (% of its path)",
            escape(
                "; ".join(
                    f"{a.segment}: {a.percent_of_path:.2f} ({a.keyframes} keyframes)"
                    for a in summary.ate_by_segment
                )
                or "—"
            ),
        ),
        ("ATE as joined, before the light's scale (% of path)", fmt(summary.ate_as_joined_pct)),
        ("frames posed", f"{summary.frames_posed} of {summary.frames}" if summary.frames else "—"),
        (f"depth {absrel}, every posed frame", fmt(summary.depth_abs_rel_all_frames)),
        (f"depth {absrel}, keyframes", fmt(summary.depth_abs_rel_keyframes)),
        ("depth AbsRel, one scale a segment", fmt(summary.depth_abs_rel_one_scale)),
        ("depth Spearman, every posed frame", fmt(summary.depth_spearman_all_frames)),
        ("depth coverage, every posed frame", fmt(summary.depth_coverage_all_frames)),
        ("the brightness guess's AbsRel, same pixels", fmt(summary.brightness_guess_abs_rel)),
        ("one mesh: Chamfer (% of radius)", fmt(summary.chamfer_pct_radius)),
        ("one mesh: off the seen surface (%)", fmt(summary.off_seen_pct)),
    ]
    table = "".join(f"<tr><th>{escape(k)}</th><td>{v}</td></tr>" for k, v in scores)
    head = (
        f'<p class="verdict {"ok" if verdict == "ok" else ""}"><b>{verdict}</b></p>'
        f"<ul>{reasons}</ul><table class='kv'>{table}</table>"
        "<p class='muted'>Depth AbsRel is "
        + (
            "taken after a least-squares scale and shift per frame (the truth is an affine "
            "proxy of depth)"
            if relative
            else "median-scaled per frame against the truth"
        )
        + "; the brightness guess (depth from shading alone, no geometry) is scored on the "
        "same pixels.</p>"
    )
    junction = {j.b: j for j in joined.junctions}
    rows = []
    for w in summary.windows:
        j = junction.get(w.name)
        jtext = "" if j is None else (fmt(j.error_pct, "%") if j.joined else escape(j.reason))
        page_of = window_pages.get(w.name)
        link = f'<a href="{escape(page_of)}">{w.name}</a>' if page_of else w.name
        rows.append(
            f"<tr><td>{link}</td><td>{w.frames}</td><td>{escape(w.status)}</td>"
            f"<td>{escape(w.pose_verdict)}</td><td>{fmt(w.registered)}</td>"
            f"<td>{fmt(w.depth_abs_rel)}</td><td>{jtext}</td></tr>"
        )
    windows = (
        "<table><tr><th>window</th><th>keyframes</th><th>status</th><th>poses</th>"
        "<th>registered</th><th>depth AbsRel</th><th>junction</th></tr>"
        + "".join(rows)
        + "</table>"
    )
    html = page(
        title=f"endopipe recording: {name}",
        subtitle=f"{summary.keyframes} keyframes in {len(plan.windows)} windows",
        generated=dt.datetime.now().strftime("%Y-%m-%d %H:%M"),
        version=__version__,
        sections=[
            {"key": "summary", "title": "Summary", "body": head},
            {
                "key": "timeline",
                "title": "Timeline",
                "body": timeline(kept, dropped, plan, joined, frames),
            },
            {"key": "unposed", "title": "Frames without a pose", "body": unposed(frames)},
            {"key": "windows", "title": "Windows", "body": windows},
            {
                "key": "trajectory",
                "title": "Trajectory",
                "body": trajectory_figure(joined, truth),
            },
            {
                "key": "scale",
                "title": "Scale from the light",
                "body": scale_figure(joined, light_line(summary)),
            },
        ],
    )
    path.write_text(html)
