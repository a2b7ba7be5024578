"""`endopipe bench`: the paper's Table 1 on fixed-seed synthetic cases, with ablations.

Every variant runs the real pipeline; variants of one case share its cached ingest, poses and
centerline stages, so only the NeRF and what follows re-run per variant.
"""

from __future__ import annotations

import csv
import time
from collections.abc import Callable
from pathlib import Path

from pydantic import BaseModel

from endopipe.pipeline.config import load_config
from endopipe.pipeline.errors import ConfigError, EndopipeError
from endopipe.pipeline.runner import Pipeline
from endopipe.stages.metrics.baselines import GUESSES

#: name -> --set overrides. "plain" is a NeRF without the prior, the near-light model and the
#: depth regularisers (and without the SfM-point depth): the paper's NeRF-endo baseline.
VARIANTS: dict[str, list[str]] = {
    "full": [],
    "no_prior": ["nerf.loss.prior=false"],
    "no_smooth": ["nerf.loss.smooth=false"],
    "no_geo": ["nerf.loss.geo=false"],
    "no_sparse": ["nerf.loss.sparse_weight=0"],
    "plain": [
        "nerf.loss.prior=false",
        "nerf.loss.smooth=false",
        "nerf.loss.geo=false",
        "nerf.loss.sparse_weight=0",
        "nerf.shading.enabled=false",
        "nerf.sampling.bounds=box",
    ],
}

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


class BenchCase(BaseModel):
    name: str
    shape: str
    frames: int
    width: int
    height: int
    seed: int
    lens: str = "pinhole"  # synth --lens
    fov_diag: float | None = None  # synth --fov-diag
    given_lens: bool = True  # False: intrinsics.json withheld, COLMAP estimates the camera
    sets: list[str] = []  # applied to this case's runs (e.g. the COLMAP camera model)


class BenchPlan(BaseModel):
    cases: list[BenchCase]
    variants: list[str]
    sets: list[str]  # applied to every run (e.g. shorter training in --quick)


def plan(
    quick: bool, cases: list[str] | None = None, variants: list[str] | None = None
) -> BenchPlan:
    """The bench's cases and variants; `cases` / `variants` keep only those names (a rerun of
    one row after a change need not pay for the whole table)."""
    full = _plan(quick)
    if not cases:  # the lens cases run when named (--case colon_barrel ...)
        full.cases = [c for c in full.cases if c.name in DEFAULT_CASES or quick]
    if cases:
        unknown = sorted(set(cases) - {c.name for c in full.cases})
        if unknown:
            names = ", ".join(c.name for c in full.cases)
            raise ConfigError(f"unknown bench case {', '.join(unknown)}; cases: {names}")
        full.cases = [c for c in full.cases if c.name in cases]
    if variants:
        unknown = sorted(set(variants) - set(full.variants))
        if unknown:
            names = ", ".join(full.variants)
            raise ConfigError(f"unknown bench variant {', '.join(unknown)}; variants: {names}")
        full.variants = [v for v in full.variants if v in variants]
    return full


COLON = {"shape": "colon", "frames": 60, "width": 320, "height": 256, "seed": 7}
DEFAULT_CASES = ("colon", "cavity")


def _plan(quick: bool) -> BenchPlan:
    if quick:
        return BenchPlan(
            cases=[
                BenchCase(name="colon_q", shape="colon", frames=24, width=160, height=128, seed=7)
            ],
            variants=["full", "no_prior", "plain"],
            sets=["nerf.train.steps=400", "mesh.method=tsdf"],
        )
    return BenchPlan(
        cases=[
            BenchCase(name="colon", shape="colon", frames=60, width=320, height=256, seed=7),
            BenchCase(name="cavity", shape="cavity", frames=60, width=320, height=256, seed=7),
            # issue 14's lens cases: the bench colon through a 110-degree barrel lens, given and
            # estimated (OPENCV: the synth lens's own model), and its pinhole twin at 110 deg
            BenchCase(**COLON, name="colon_wide", fov_diag=110.0),
            BenchCase(**COLON, name="colon_barrel", lens="barrel"),
            BenchCase(
                **COLON,
                name="colon_barrel_est",
                lens="barrel",
                given_lens=False,
                sets=["poses.camera_model=OPENCV"],
            ),
        ],
        variants=list(VARIANTS),
        sets=[],
    )


def run_bench(
    pipe: Pipeline,
    workdir: Path,
    bench_plan: BenchPlan,
    prepare_case,
    console,
    extra_sets: list[str] | None = None,
    on_row: Callable[[list[dict]], None] | None = None,
) -> list[dict]:
    """Run every case x variant; return one row per run (the table's rows). A run that fails
    is a row with its one-line error and whatever its fresh stages measured; the bench goes on.
    `on_row` gets the rows so far after each run (to write results as they come)."""
    rows: list[dict] = []
    for case in bench_plan.cases:
        src = synth_input(workdir / "inputs", case, console)
        source = src / "video.mp4"
        if not case.given_lens:  # the same frames and truth, the camera left to COLMAP
            source = workdir / "inputs" / case.name
            source.mkdir(parents=True, exist_ok=True)
            for part in ("video.mp4", "gt"):
                if not (source / part).exists():
                    (source / part).symlink_to((src / part).resolve())
        for variant in bench_plan.variants:
            sets = [*bench_plan.sets, *case.sets, *VARIANTS[variant], *(extra_sets or [])]
            configs = load_config(pipe.stages, [], sets)
            case_dir = prepare_case(source, workdir / "runs", case.name, None)
            console.print(f"[bold cyan]{case.name} / {variant}[/bold cyan]")
            t0 = time.perf_counter()
            error = None
            try:
                pipe.run(case_dir, configs, console=console, quiet=False)
            except EndopipeError as e:
                error = str(e).splitlines()[0] if str(e) else type(e).__name__
                console.print(f"[red]{case.name} / {variant} failed:[/red] {error}")
            elapsed = time.perf_counter() - t0
            fresh = {p.stage for p in pipe.status(case_dir, configs) if p.fresh}
            rows.append(collect_row(pipe, case_dir, case.name, variant, elapsed, fresh, error))
            if on_row is not None:
                on_row(rows)
    return rows


def synth_input(inputs: Path, case: BenchCase, console) -> Path:
    """The case's synthetic input (written once; cases that differ only in what they are told
    share it)."""
    from endopipe.commands.synth import SynthConfig, generate_case

    lens = "" if case.lens == "pinhole" else f"_{case.lens}"
    fov = "" if case.fov_diag is None else f"_fov{case.fov_diag:g}"
    src = inputs / f"{case.shape}_s{case.seed}_{case.frames}x{case.width}x{case.height}{lens}{fov}"
    if not (src / "intrinsics.json").is_file():
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
            ),
        )
    return src


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
    summary = {k: (m.summary if m else {}) for k, m in manifests.items()}
    depth = summary.get("depth", {})
    med = depth.get("median_scaled") or {}
    guesses = depth.get("baselines") or {}
    mesh = summary.get("mesh", {})
    poses = summary.get("poses", {})
    return {
        "case": case,
        "variant": variant,
        "error": error,
        **{k: med.get(k) for k in ("abs_rel", "sq_rel", "rmse", "rmse_log", "delta1")},
        "coverage": med.get("coverage"),
        **{
            f"{name}_{k}": ((guesses.get(name) or {}).get("median_scaled") or {}).get(k)
            for k in ("abs_rel", "delta1")
            for name in GUESSES
        },
        "chamfer": mesh.get("chamfer"),
        "chamfer_pct_radius": mesh.get("chamfer_pct_radius"),
        "off_seen_pct": mesh.get("off_seen_pct"),
        "prior": summary.get("centerline", {}).get("kind"),
        "psnr": depth.get("heldout_psnr"),
        "ssim": depth.get("heldout_ssim"),
        "registered": poses.get("registered_fraction"),
        "ate_pct": poses.get("ate_percent_of_path"),
        "depth_ms": depth.get("ms_per_frame"),
        "wall_s": sum(m.wall_s for m in manifests.values() if m),
        "peak_mb": max((m.peak_rss_mb for m in manifests.values() if m), default=None),
    }


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
