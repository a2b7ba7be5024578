"""The bench's results as files: the table's CSV and markdown (ours beside the two guesses, and
the metric rows beside the stereo matcher), and the pose sweep's, with the tally its verdict is
judged by."""

from __future__ import annotations

import csv
from pathlib import Path

from endopipe.stages.metrics.baselines import GUESSES

COLUMNS = (
    "case",
    "variant",
    "error",
    "abs_rel",
    "sq_rel",
    "rmse",
    "rmse_log",
    "delta1",
    "coverage",
    "radial_abs_rel",
    "brightness_abs_rel",
    "radial_delta1",
    "brightness_delta1",
    "unscaled_abs_rel",
    "stereo_unscaled_abs_rel",
    "stereo_coverage",
    "chamfer",
    "chamfer_pct_radius",
    "off_seen_pct",
    "prior",
    "psnr",
    "ssim",
    "registered",
    "ate_pct",
    "depth_ms",
    "wall_s",
    "peak_mb",
)


def write_csv(path: Path, rows: list[dict]) -> None:
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=COLUMNS)
        writer.writeheader()
        writer.writerows(rows)


def markdown_table(rows: list[dict]) -> str:
    """The paper's Table 1 shape, plus coverage, Chamfer, image metrics, timings and memory;
    then ours beside the two guesses (`guesses_table`)."""
    head = (
        "| case | variant | AbsRel | SqRel | RMSE | RMSElog | δ<1.25 | coverage | Chamfer "
        "| Chamfer %r | off seen % | prior | PSNR | SSIM | registered | ATE % | depth ms "
        "| wall s | peak MB |"
    )
    lines = [head, "|" + "---|" * 19]
    for r in rows:
        cells = [r["case"], _variant(r)]
        cells += [_fmt(r[k], 4) for k in ("abs_rel", "sq_rel", "rmse", "rmse_log", "delta1")]
        cells += [_fmt(r.get("coverage"), 3)]
        cells += [_fmt(r["chamfer"], 3), _fmt(r["chamfer_pct_radius"], 2)]
        cells += [_fmt(r.get("off_seen_pct"), 1), str(r.get("prior") or "–")]
        cells += [_fmt(r["psnr"], 2), _fmt(r["ssim"], 3), _fmt(r["registered"], 2)]
        cells += [_fmt(r["ate_pct"], 2), _fmt(r["depth_ms"], 0), _fmt(r["wall_s"], 0)]
        cells += [_fmt(r["peak_mb"], 0)]
        lines.append("| " + " | ".join(cells) + " |")
    lines += ["", guesses_table(rows)]
    metric = metric_table(rows)
    if metric:
        lines += ["", metric]
    failed = [r for r in rows if r.get("error")]
    if failed:
        lines.append("")
        lines += [f"- {r['case']} / {r['variant']} failed: {r['error']}" for r in failed]
    return "\n".join(lines)


def guesses_table(rows: list[dict]) -> str:
    """Ours beside the radial and brightness guesses (stages.metrics.baselines), per-frame
    median scaling on the same pixels; "no" under "beats both" when either guess has an
    AbsRel at least as low as ours."""
    lines = [
        "Ours beside two guesses that look at no geometry (radial: the image centre is far; "
        "brightness: depth = 1/√brightness), per-frame median scaling, on the pixels ours is "
        "scored on:",
        "",
        "| case | variant | AbsRel ours | AbsRel radial | AbsRel brightness | δ<1.25 ours "
        "| δ<1.25 radial | δ<1.25 brightness | beats both |",
        "|" + "---|" * 9,
    ]
    for r in rows:
        cells = [r["case"], _variant(r), _fmt(r.get("abs_rel"), 4)]
        cells += [_fmt(r.get(f"{name}_abs_rel"), 4) for name in GUESSES]
        cells += [_fmt(r.get("delta1"), 4)]
        cells += [_fmt(r.get(f"{name}_delta1"), 4) for name in GUESSES]
        cells.append(_beats(r))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def metric_table(rows: list[dict]) -> str:
    """Rows whose poses were metric: the depth as it is (no scaling), beside the stereo
    matcher's own where a rig gave one ("" when no row is metric)."""
    rows = [r for r in rows if r.get("unscaled_abs_rel") is not None]
    if not rows:
        return ""
    lines = [
        "Metric poses: depth scored as it is, in millimetres (no scaling), beside the stereo "
        "matcher's own depth on our pixels where it matched:",
        "",
        "| case | variant | AbsRel ours | coverage ours | AbsRel stereo | coverage stereo |",
        "|" + "---|" * 6,
    ]
    for r in rows:
        cells = [r["case"], _variant(r), _fmt(r["unscaled_abs_rel"], 4)]
        cells += [_fmt(r.get("coverage"), 3), _fmt(r.get("stereo_unscaled_abs_rel"), 4)]
        cells += [_fmt(r.get("stereo_coverage"), 3)]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _beats(row: dict) -> str:
    ours = row.get("abs_rel")
    theirs = [row.get(f"{name}_abs_rel") for name in GUESSES]
    if ours is None or any(t is None for t in theirs):
        return "–"
    return "yes" if all(ours < t for t in theirs) else "**no**"


def _variant(row: dict) -> str:
    return row["variant"] + (" (failed)" if row.get("error") else "")


def _fmt(value, digits: int) -> str:
    if value is None:
        return "–"
    return f"{value:.{digits}f}"


# ------------------------------------------------------------------ the pose sweep's table

POSE_COLUMNS = (
    "case",
    "shape",
    "seed",
    "contrast",
    "vignetting",
    "lens",
    "error",
    "registered",
    "ate_pct",
    "mapper",
    "verdict",
    "reasons",
    "doubtful_frames",
    "doubtful_count",
    "disagreement_pct",
    "other",
    "other_ate_pct",
    "depth_drift",
    "poses_s",
    "features_s",
    "matching_s",
    "global_mapping_s",
    "incremental_mapping_s",
)
#: The sweep's yardsticks: poses within 2% of the path are good, beyond 5% wrong.
GOOD_ATE_PCT = 2.0
BAD_ATE_PCT = 5.0


def _short_reasons(reasons: str) -> str:
    """The verdict's reasons without their thresholds ('... 12.3x along the path (> 4x)' ->
    '... 12.3x along the path'), for the markdown table; the CSV keeps them whole."""
    return "; ".join(r.split(" (")[0] for r in reasons.split("; ") if r)


def write_pose_csv(path: Path, rows: list[dict]) -> None:
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=POSE_COLUMNS)
        writer.writeheader()
        writer.writerows(rows)


def pose_table(rows: list[dict]) -> str:
    """The sweep's markdown table, then the tally the verdict is judged by."""
    lines = [
        "| case | shape | seed | contrast | vignetting | lens | registered | ATE % | mapper "
        "| verdict | reasons | doubtful frames | other mapper | disagreement % | poses s |",
        "|" + "---|" * 15,
    ]
    for r in rows:
        cells = [r["case"], r["shape"], str(r["seed"]), f"{r['contrast']:g}"]
        cells += [f"{r['vignetting']:g}", r["lens"], _fmt(r["registered"], 2)]
        cells += [_fmt(r["ate_pct"], 2), r["mapper"] or "–"]
        cells += ["failed" if r.get("error") else (r["verdict"] or "–")]
        cells += [_short_reasons(r["reasons"]) or "–"]
        cells += ["–" if r["doubtful_count"] is None else str(r["doubtful_count"])]
        other = r["other"] or "–"
        if r.get("other_ate_pct") is not None:
            other += f" (ATE {r['other_ate_pct']:.2f}%)"
        cells += [other, _fmt(r["disagreement_pct"], 2), _fmt(r["poses_s"], 0)]
        lines.append("| " + " | ".join(cells) + " |")
    lines += ["", pose_tally(rows)]
    failed = [r for r in rows if r.get("error")]
    if failed:
        lines.append("")
        lines += [f"- {r['case']} failed: {r['error']}" for r in failed]
    return "\n".join(lines)


def pose_tally(rows: list[dict]) -> str:
    """One line: how many cases are good (ATE ≤ 2%), how many wrong (> 5%) and how many of
    those the verdict caught, how many good ones it called doubtful."""
    scored = [r for r in rows if r["ate_pct"] is not None]
    good = [r for r in scored if r["ate_pct"] <= GOOD_ATE_PCT]
    bad = [r for r in scored if r["ate_pct"] > BAD_ATE_PCT]
    line = (
        f"ATE ≤ {GOOD_ATE_PCT:g}%: {len(good)} of {len(rows)} cases; "
        f"ATE > {BAD_ATE_PCT:g}%: {len(bad)}, of them marked doubtful: "
        f"{sum(r['verdict'] == 'doubtful' for r in bad)}; "
        f"ATE ≤ {GOOD_ATE_PCT:g}% marked doubtful: {sum(r['verdict'] == 'doubtful' for r in good)}"
    )
    unscored = len(rows) - len(scored)
    line += f"; no ATE (failed or no ground truth): {unscored}" if unscored else ""
    # the mappers not kept, each judged on its own: does the verdict catch a wrong one?
    alone = [
        (r["other_ate_pct"], not r["other"].split(": ", 1)[-1].startswith("sound"))
        for r in rows
        if r.get("other_ate_pct") is not None
    ]
    if alone:
        wrong = [doubted for ate, doubted in alone if ate > BAD_ATE_PCT]
        right = [doubted for ate, doubted in alone if ate <= GOOD_ATE_PCT]
        line += (
            f". The mappers not kept, judged alone: ATE > {BAD_ATE_PCT:g}%: {len(wrong)}, "
            f"marked doubtful: {sum(wrong)}; ATE ≤ {GOOD_ATE_PCT:g}% marked doubtful: "
            f"{sum(right)} of {len(right)}"
        )
    return line
