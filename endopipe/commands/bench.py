"""`endopipe bench`: the paper's Table 1 on fixed-seed synthetic cases, with ablations; and
`--sweep poses`, the pose stage alone over cases that vary what SfM finds hard.

Every variant runs the real pipeline; variants of one case share its cached ingest, poses and
centerline stages, so only the NeRF and what follows re-run per variant.
"""

from __future__ import annotations

import csv
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from pydantic import BaseModel

from endopipe.pipeline.config import load_config
from endopipe.pipeline.errors import ConfigError, EndopipeError
from endopipe.pipeline.runner import Pipeline
from endopipe.stages.centerline.summary import CenterlineSummary
from endopipe.stages.depth.summary import DepthSummary
from endopipe.stages.mesh.summary import MeshSummary
from endopipe.stages.metrics.baselines import GUESSES
from endopipe.stages.metrics.scores import DepthScores
from endopipe.stages.poses.summary import PosesSummary

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
    texture_contrast: float = 1.0  # synth --texture-contrast
    vignetting: float = 0.0  # synth --vignetting
    deform: str = "none"  # synth --deform
    still_camera: bool = False  # synth --still-camera
    layout: str = "endopipe"  # synth --layout: a data set's own layout, read by its reader
    stereo: bool = False  # synth --stereo: a right eye too (hamlyn, scared)
    sets: list[str] = []  # applied to this case's runs (e.g. the COLMAP camera model)


class BenchPlan(BaseModel):
    cases: list[BenchCase]
    variants: list[str]
    sets: list[str]  # applied to every run (e.g. shorter training in --quick)
    until: str | None = None  # the last stage each run goes to (None: the whole DAG)


#: `--sweep` name -> what it measures.
SWEEPS = {"poses": "the poses stage alone on cases that vary shape, seed, texture and optics"}


def plan(
    quick: bool,
    cases: list[str] | None = None,
    variants: list[str] | None = None,
    sweep: str | None = None,
) -> BenchPlan:
    """The bench's cases and variants; `cases` / `variants` keep only those names (a rerun of
    one row after a change need not pay for the whole table). `sweep` replaces the table's
    cases by a sweep's (one run each, up to that stage)."""
    if sweep is not None:
        full = _sweep_plan(sweep, quick, variants)
    else:
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
#: a still camera on the cavity's wall pulled by a tool in view
PULL_STILL = {
    "shape": "cavity",
    "frames": 120,
    "width": 320,
    "height": 256,
    "seed": 7,
    "deform": "pull",
    "still_camera": True,
}
DEFAULT_CASES = ("colon", "cavity")
SWEEP_SIZE = {"frames": 60, "width": 320, "height": 256}

#: The pose sweep: colon and cavity, several seeds, texture contrast 1 / 0.75 / 0.5 / 0.3,
#: vignetting, a wide barrel lens (given). The two seed-7 cases are the bench's colon and cavity.
POSE_SWEEP = [
    BenchCase(**SWEEP_SIZE, name="colon_s7", shape="colon", seed=7),
    BenchCase(**SWEEP_SIZE, name="cavity_s7", shape="cavity", seed=7),
    BenchCase(**SWEEP_SIZE, name="colon_s3_c0.75", shape="colon", seed=3, texture_contrast=0.75),
    BenchCase(**SWEEP_SIZE, name="cavity_s3_c0.75", shape="cavity", seed=3, texture_contrast=0.75),
    BenchCase(**SWEEP_SIZE, name="colon_s11_c0.5", shape="colon", seed=11, texture_contrast=0.5),
    BenchCase(**SWEEP_SIZE, name="cavity_s11_c0.5", shape="cavity", seed=11, texture_contrast=0.5),
    BenchCase(**SWEEP_SIZE, name="cavity_s5_v0.4", shape="cavity", seed=5, vignetting=0.4),
    BenchCase(**SWEEP_SIZE, name="colon_s5_barrel", shape="colon", seed=5, lens="barrel"),
    # nearly textureless: where the two mappers start to part
    BenchCase(**SWEEP_SIZE, name="colon_s13_c0.3", shape="colon", seed=13, texture_contrast=0.3),
    BenchCase(**SWEEP_SIZE, name="cavity_s13_c0.3", shape="cavity", seed=13, texture_contrast=0.3),
]


def _sweep_plan(sweep: str, quick: bool, variants: list[str] | None) -> BenchPlan:
    if sweep not in SWEEPS:
        raise ConfigError(f"unknown sweep {sweep}; sweeps: {', '.join(SWEEPS)}")
    if quick or variants:
        raise ConfigError("--sweep runs its own cases once each: no --quick, no --variant")
    return BenchPlan(cases=list(POSE_SWEEP), variants=["full"], sets=[], until="poses")


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
            # the lens cases: the bench colon through a 110-degree barrel lens, given and
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
            # a 140-degree fisheye, the lens estimated as any scope's is (SIMPLE_RADIAL, which
            # bends back inside it: re-fitted as a fisheye, poses.unfold_lens)
            BenchCase(**COLON, name="colon_fisheye_est", lens="fisheye", given_lens=False),
            # moving anatomy: the bench colon breathing (the same camera path), and a still
            # camera on the cavity's wall pulled by a tool in view (run as a user would: the
            # poses stage finds the camera still and poses it once)
            BenchCase(**COLON, name="colon_breathe", deform="breathe"),
            BenchCase(**PULL_STILL, name="pull_still"),
            # the same in EndoNeRF's layout, its depth/ matched from a right eye as EndoNeRF's
            # own: the depth the data set ships supervises, in mm
            BenchCase(**PULL_STILL, name="pull_still_endonerf", layout="endonerf", stereo=True),
            # a rectified Hamlyn sequence with both eyes, read as the data set ships (no GT
            # poses used: the stereo gives the scale), moving and still
            BenchCase(**COLON, name="hamlyn_stereo", layout="hamlyn", stereo=True),
            BenchCase(
                **COLON, name="hamlyn_stereo_still", layout="hamlyn", stereo=True, still_camera=True
            ),
            # the same still rig over the cavity: at its distances (12-33 mm) the right eye sees
            # most of the left one's view, as a laparoscope's does; the colon's near wall (8 mm)
            # puts 30% of the width out of the right eye's sight
            BenchCase(
                **{**COLON, "shape": "cavity"},
                name="hamlyn_stereo_still_cavity",
                layout="hamlyn",
                stereo=True,
                still_camera=True,
            ),
            # C3VD's layout: its calibration read as the lens, its model mesh the Chamfer truth
            BenchCase(**COLON, name="c3vd_layout", layout="c3vd"),
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
            layout=other_layout(case.layout, STEREO_BASELINE_MM if case.stereo else None),
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


def _score(block: DepthScores | None, name: str) -> float | None:
    """One score of a protocol block (AttributeError for a name DepthScores does not have)."""
    return getattr(block, name) if block is not None else None


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
