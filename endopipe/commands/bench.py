"""`endopipe bench`: the paper's Table 1 on fixed-seed synthetic cases, with ablations; and
`--sweep poses`, the pose stage alone over cases that vary what SfM finds hard.

Every variant runs the real pipeline; variants of one case share its cached ingest, poses and
centerline stages, so only the NeRF and what follows re-run per variant. This module runs the
plan and reads each run's row from its stages; what runs is bench_plan.py, the CSV and markdown
tables bench_tables.py.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from endopipe.commands.bench_plan import VARIANTS, BenchCase, BenchPlan
from endopipe.commands.bench_tables import POSE_COLUMNS
from endopipe.pipeline.config import load_config
from endopipe.pipeline.errors import EndopipeError
from endopipe.pipeline.runner import Pipeline
from endopipe.stages.centerline.summary import CenterlineSummary
from endopipe.stages.depth.summary import DepthSummary
from endopipe.stages.mesh.summary import MeshSummary
from endopipe.stages.metrics.baselines import GUESSES
from endopipe.stages.metrics.scores import DepthScores
from endopipe.stages.poses.summary import PosesSummary


def run_bench(
    pipe: Pipeline,
    workdir: Path,
    bench_plan: BenchPlan,
    prepare_case,
    console,
    extra_sets: list[str] | None = None,
    on_row: Callable[[list[dict]], None] | None = None,
    collect: Callable[..., dict] | None = None,
) -> list[dict]:
    """Run every case x variant; return one row per run (the table's rows). A run that fails
    is a row with its one-line error and whatever its fresh stages measured; the bench goes on.
    `on_row` gets the rows so far after each run (to write results as they come); `collect`
    makes a row as `collect_row` does, but from the BenchCase (default: `collect_row`)."""
    rows: list[dict] = []
    for case in bench_plan.cases:
        source = case_input(workdir / "inputs", case, console)
        for variant in bench_plan.variants:
            sets = [*bench_plan.sets, *case.sets, *VARIANTS[variant], *(extra_sets or [])]
            configs = load_config(pipe.stages, [], sets)
            case_dir = prepare_case(source, workdir / "runs", case.name, None)
            console.print(f"[bold cyan]{case.name} / {variant}[/bold cyan]")
            t0 = time.perf_counter()
            error = None
            try:
                pipe.run(case_dir, configs, until=bench_plan.until, console=console, quiet=False)
            except EndopipeError as e:
                error = str(e).splitlines()[0] if str(e) else type(e).__name__
                console.print(f"[red]{case.name} / {variant} failed:[/red] {error}")
            elapsed = time.perf_counter() - t0
            fresh = {p.stage for p in pipe.status(case_dir, configs) if p.fresh}
            if collect is None:
                row = collect_row(pipe, case_dir, case.name, variant, elapsed, fresh, error)
            else:
                row = collect(pipe, case_dir, case, variant, elapsed, fresh, error)
            rows.append(row)
            if on_row is not None:
                on_row(rows)
    return rows


def case_input(inputs: Path, case: BenchCase, console) -> Path:
    """What the pipeline reads for `case`: the synthetic video (its case folder gives the
    intrinsics and ground truth), or without the lens a folder of links to its video and truth
    only (the camera left to COLMAP)."""
    src = synth_input(inputs, case, console)
    if case.layout != "endopipe":  # read as the data set ships; its gt/ beside it scores it
        return src
    if case.given_lens:
        return src / "video.mp4"
    source = inputs / case.name
    source.mkdir(parents=True, exist_ok=True)
    for part in ("video.mp4", "gt"):
        if not (source / part).exists():
            (source / part).symlink_to((src / part).resolve())
    return source


def synth_input(inputs: Path, case: BenchCase, console) -> Path:
    """The case's synthetic input (written once; cases that differ only in what they are told
    share it)."""
    from endopipe.commands.synth import STEREO_BASELINE_MM, other_layout
    from endopipe.synth import SynthConfig, generate_case

    src = inputs / input_name(case)
    if not (src / "gt" / "synth.json").is_file():
        console.print(f"[bold]synthesising[/bold] {src.name}")
        generate_case(
            src,
            SynthConfig(
                seed=case.seed,
                frames=case.frames,
                width=case.width,
                height=case.height,
                shape=case.shape,
                lens=case.lens,
                fov_diag_deg=case.fov_diag,
                texture_contrast=case.texture_contrast,
                vignetting=case.vignetting,
                deform=case.deform,
                still_camera=case.still_camera,
                stereo_baseline_mm=STEREO_BASELINE_MM if case.stereo else None,
            ),
            layout=other_layout(
                case.layout, STEREO_BASELINE_MM if case.stereo else None, case.lens
            ),
        )
    return src


def input_name(case: BenchCase) -> str:
    """The synthetic input's folder name: everything that changes the rendered frames."""
    lens = "" if case.lens == "pinhole" else f"_{case.lens}"
    fov = "" if case.fov_diag is None else f"_fov{case.fov_diag:g}"
    look = "" if case.texture_contrast == 1.0 else f"_c{case.texture_contrast:g}"
    look += "" if case.vignetting == 0.0 else f"_v{case.vignetting:g}"
    look += "" if case.deform == "none" else f"_{case.deform}"
    look += "_still" if case.still_camera else ""
    look += "" if case.layout == "endopipe" else f"_{case.layout}"
    look += "_stereo" if case.stereo else ""
    return f"{case.shape}_s{case.seed}_{case.frames}x{case.width}x{case.height}{lens}{fov}{look}"


def collect_row(
    pipe: Pipeline,
    case_dir: Path,
    case: str,
    variant: str,
    elapsed: float,
    fresh: set[str] | None = None,
    error: str | None = None,
) -> dict:
    """Metrics from the stage manifests, which the engine finds (only stages in `fresh`, when
    given: after a failure a later stage's folder still holds the previous variant's results);
    wall = every stage's own time (cached ones included)."""
    names = [s.name for s in pipe.stages if fresh is None or s.name in fresh]
    manifests = {n: pipe.manifest(case_dir, n) for n in names}

    def summary(name: str) -> Any:
        """The stage's typed summary, through its view; None when it did not run for this row."""
        return pipe.view(case_dir, name).summary if manifests.get(name) else None

    depth: DepthSummary | None = summary("depth")
    mesh: MeshSummary | None = summary("mesh")
    poses: PosesSummary | None = summary("poses")
    centerline: CenterlineSummary | None = summary("centerline")
    med = depth.median_scaled if depth else None
    guesses = (depth.baselines if depth else None) or {}
    stereo = guesses.get("stereo")
    return {
        "case": case,
        "variant": variant,
        "error": error,
        **{k: _score(med, k) for k in ("abs_rel", "sq_rel", "rmse", "rmse_log", "delta1")},
        "coverage": med.coverage if med else None,
        **{
            f"{name}_{k}": _score(guesses[name].median_scaled if name in guesses else None, k)
            for k in ("abs_rel", "delta1")
            for name in GUESSES
        },
        "unscaled_abs_rel": _score(depth.unscaled if depth else None, "abs_rel"),
        "stereo_unscaled_abs_rel": _score(stereo.unscaled if stereo else None, "abs_rel"),
        "stereo_coverage": stereo.unscaled.coverage if stereo and stereo.unscaled else None,
        "chamfer": mesh.chamfer if mesh else None,
        "chamfer_pct_radius": mesh.chamfer_pct_radius if mesh else None,
        "off_seen_pct": mesh.off_seen_pct if mesh else None,
        "prior": centerline.kind if centerline else None,
        "psnr": depth.heldout_psnr if depth else None,
        "ssim": depth.heldout_ssim if depth else None,
        "registered": poses.registered_fraction if poses else None,
        "ate_pct": poses.ate_percent_of_path if poses else None,
        "depth_ms": depth.ms_per_frame if depth else None,
        "wall_s": sum(m.wall_s for m in manifests.values() if m),
        "peak_mb": max((m.peak_rss_mb for m in manifests.values() if m), default=None),
    }


def _score(block: DepthScores | None, name: str) -> float | None:
    """One score of a protocol block (AttributeError for a name DepthScores does not have)."""
    return getattr(block, name) if block is not None else None


def pose_row(
    pipe: Pipeline,
    case_dir: Path,
    case: BenchCase,
    variant: str,
    elapsed: float,
    fresh: set[str] | None = None,
    error: str | None = None,
) -> dict:
    """One sweep case: what it varies, then the poses manifest's measures and verdict (only a
    poses folder this run produced: a failed run's folder may hold an earlier run's)."""
    ok = fresh is None or "poses" in fresh
    manifest = pipe.manifest(case_dir, "poses") if ok else None
    view = pipe.view(case_dir, "poses") if manifest else None
    s: PosesSummary | None = view.summary if view else None
    verdict = view.verdict() if view else None
    others = verdict.others if verdict else {}
    return {
        "case": case.name,
        "shape": case.shape,
        "seed": case.seed,
        "contrast": case.texture_contrast,
        "vignetting": case.vignetting,
        "lens": lens_label(case),
        "error": error,
        **_pose_measures(s),
        "other": "; ".join(f"{m}: {_first_clause(why)}" for m, why in others.items()),
    }


def _pose_measures(s: PosesSummary | None) -> dict:
    """The sweep's columns from a poses summary (None each without one, "" for the texts)."""
    if s is None:
        names = ("registered", "ate_pct", "mapper", "verdict", "doubtful_count")
        names += ("disagreement_pct", "other_ate_pct", "depth_drift", "poses_s")
        return dict.fromkeys(names + POSE_COLUMNS[-4:]) | {"reasons": "", "doubtful_frames": ""}
    return {
        "registered": s.registered_fraction,
        "ate_pct": s.ate_percent_of_path,
        "mapper": s.mapper or None,
        "verdict": s.verdict,
        "reasons": s.verdict_reasons,
        "doubtful_frames": s.doubtful_frames,
        "doubtful_count": count_ranges(s.doubtful_frames),
        "disagreement_pct": s.mappers_disagreement_pct,
        "other_ate_pct": next(iter(s.others_ate_percent.values()), None),
        "depth_drift": s.depth_drift,
        "poses_s": s.seconds,
        **{k: s.timings.get(k) for k in POSE_COLUMNS[-4:]},
    }


def lens_label(case: BenchCase) -> str:
    """'pinhole', 'barrel 110°', 'pinhole 110°' (the diagonal field of view when not the
    synth's default pinhole); '(estimated)' when COLMAP is not told the lens."""
    from endopipe.synth.lens import LENSES

    fov = case.fov_diag if case.fov_diag is not None else LENSES[case.lens].fov_diag_deg
    label = case.lens + ("" if fov is None else f" {fov:g}°")
    return label + ("" if case.given_lens else " (estimated)")


def count_ranges(text: str) -> int:
    """'0-2, 7' -> 4: the frames a ranges string names."""
    count = 0
    for part in filter(None, (p.strip() for p in text.split(","))):
        lo, _, hi = part.partition("-")
        count += int(hi or lo) - int(lo) + 1
    return count


def _first_clause(text: str) -> str:
    """'doubtful: scale drift ...; 12% of the path ...' -> 'doubtful'."""
    return text.split(":")[0].split(";")[0].strip()
