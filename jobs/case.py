"""One case as a job (a batch's case, a recording's window), in whatever process or cluster job
the executor gives it.

The composition root hands in how to build the pipeline and prepare a case folder, so this
module needs no stage list of its own and stays picklable by reference.
"""

from __future__ import annotations

import time
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from endopipe.jobs.rows import CaseRow, CaseTask, numeric_leaves
from endopipe.pipeline.cache import Manifest
from endopipe.pipeline.errors import EndopipeError, one_line
from endopipe.pipeline.executors import limit_threads
from endopipe.pipeline.runner import Pipeline, RunRecord, read_runs
from endopipe.pipeline.stage import CaseInfo

if TYPE_CHECKING:
    from endopipe.stages.io.added import AddedInputs

#: prepare_case(input, workdir, name, intrinsics, input_format, added) -> the case folder.
PrepareCase = Callable[[Path, Path, str | None, Path | None, str | None, Any], Path]


def task_added(task: CaseTask) -> AddedInputs:
    """The right eye and depth prior a task carries, as the input opens them."""
    from endopipe.stages.io.added import AddedInputs

    return AddedInputs(
        right=Path(task.right) if task.right else None,
        baseline_mm=task.baseline_mm,
        depth_prior=Path(task.depth_prior) if task.depth_prior else None,
    )


def process_case(
    task: CaseTask, build_pipeline: Callable[[], Pipeline], prepare_case: PrepareCase
) -> CaseRow:
    """Run (or, with `task.check_only`, only check) one case; it never raises: a failure
    becomes the row's one-line reason.

    With `task.check_only` it changes nothing and only says whether every stage is already
    fresh (status "ok"), the input cannot be used ("failed"), or something would run
    ("pending").
    """
    from endopipe.stages.io.sources import open_input

    if task.threads:
        limit_threads(task.threads)
    t0, started = time.perf_counter(), time.time()
    row = CaseRow(case=task.name, status="failed", reader=task.reader, input=task.input)
    workdir, path = Path(task.workdir), Path(task.input)
    intrinsics = Path(task.intrinsics) if task.intrinsics else None
    added = task_added(task)
    case_dir = workdir / task.name
    try:
        pipe = build_pipeline()  # imports the stages: not counted in the case's wall time
        t0, started = time.perf_counter(), time.time()
        configs = {
            s.name: s.Config.model_validate(task.configs.get(s.name, {})) for s in pipe.stages
        }
        selected = [s.name for s in pipe.selection(task.until)]
        row.failed_stage = selected[0]  # reading the input is the first stage's job
        source = open_input(path, intrinsics, format=task.reader, added=added)
        gt = source.ground_truth()
        row.gt_kind = gt.kind if gt is not None else ""
        row.failed_stage = None
        if task.check_only:
            if (
                task.force
                or task.from_stage
                or not _all_fresh(pipe, case_dir, path, source, configs, task.until)
            ):
                row.status = "pending"
                return row
            row.stages_cached = selected
        else:
            case_dir = prepare_case(path, workdir, task.name, intrinsics, task.reader, added)
            record = pipe.run(
                case_dir,
                configs,
                until=task.until,
                from_stage=task.from_stage,
                force=task.force,
                quiet=True,
            )
            row.stages_ran = [s.stage for s in record.stages if s.status == "ran"]
            row.stages_cached = [s.stage for s in record.stages if s.status == "cached"]
        manifests = {n: m for n in selected if (m := pipe.manifest(case_dir, n)) is not None}
        for name, manifest in manifests.items():
            row.compute_s += manifest.wall_s
            row.peak_rss_mb = max(row.peak_rss_mb, manifest.peak_rss_mb)
            summary = pipe.view(case_dir, name).summary  # the stage's typed model
            for key, value in numeric_leaves(summary.model_dump(mode="json")).items():
                row.metrics[f"{name}.{key}"] = value
        if "poses" in manifests:
            note_pose_verdict(row, pipe.folder(case_dir, "poses"))
        row.wall_s = producing_wall_s(case_dir, manifests)
        report = _report_page(pipe, case_dir)
        row.report = report.relative_to(workdir).as_posix() if report else None
        row.status = "ok"
    except EndopipeError as e:
        row.reason = one_line(e)
        _note_failed_stage(row, case_dir, started)
    except Exception as e:  # an endopipe bug: one line in the row, the traceback in a log
        if task.check_only:  # let the real run meet it and report it
            row.status = "pending"
            return row
        row.reason = f"internal error: {type(e).__name__}: {one_line(e)}"
        log = workdir / ".batch" / "logs" / f"{task.name}.log"
        try:
            log.parent.mkdir(parents=True, exist_ok=True)
            log.write_text(traceback.format_exc())
            row.reason += f" (traceback in {log})"
        except OSError:
            pass
        _note_failed_stage(row, case_dir, started)
    row.this_batch_s = time.perf_counter() - t0
    if row.status != "ok":
        row.wall_s = row.this_batch_s
    return row


def note_pose_verdict(row: CaseRow, folder: Path) -> None:
    """The poses' verdict into the row, through the poses stage's view (nothing for a folder
    written before the verdict existed; an unreadable one is said, not raised: the case ran)."""
    from endopipe.stages.poses.view import PosesView

    try:
        verdict = PosesView(folder).verdict()
    except Exception as e:  # noqa: BLE001 - one bad file must not fail a finished case
        row.pose_reasons = f"verdict.json unreadable: {one_line(e)}"
        return
    if verdict is None:
        return
    row.pose_verdict = verdict.status
    row.pose_reasons = "; ".join(verdict.reasons)
    row.mapper = verdict.mapper
    row.doubtful_frames = len(verdict.doubtful())


def producing_wall_s(case_dir: Path, manifests: dict[str, Manifest]) -> float:
    """The wall time of the runs that made these stage outputs: each run record (counted once)
    in which one of them ran; a stage with no such record counts its own time."""
    records = read_runs(case_dir)
    producers: set[int] = set()
    alone = 0.0
    for name, manifest in manifests.items():
        n = next((n for n, r in enumerate(records) if _made(r, name, manifest)), None)
        if n is None:
            alone += manifest.wall_s
        else:
            producers.add(n)
    return sum(records[n].wall_s for n in producers) + alone


def _made(record: RunRecord, stage: str, manifest: Manifest) -> bool:
    """Whether `record` is the run that wrote `manifest` (same stage, ran, same wall time)."""
    return any(
        s.stage == stage and s.status == "ran" and abs(s.wall_s - manifest.wall_s) < 1e-9
        for s in record.stages
    )


def _report_page(pipe: Pipeline, case_dir: Path) -> Path | None:
    """The case's report page, through the report stage's view; None when there is none."""
    if "report" not in pipe.by_name:
        return None
    from endopipe.stages.report.view import ReportView

    page = ReportView(pipe.folder(case_dir, "report")).page
    return page if page.is_file() else None


def _all_fresh(
    pipe: Pipeline, case_dir: Path, path: Path, source: Any, configs: dict, until: str | None
) -> bool:
    """Whether the case folder is this input's and every selected stage is fresh (the input
    is digested only when the folder is there to compare with)."""
    if not (case_dir / "case.json").is_file():
        return False
    info = CaseInfo.load(case_dir)
    if info.input != str(path.resolve()) or info.input_digest != source.digest():
        return False
    return all(p.fresh for p in pipe.plan(case_dir, info, configs, until))


def _note_failed_stage(row: CaseRow, case_dir: Path, started: float) -> None:
    """Which stages ran before the failure, and which failed: from this run's record."""
    runs = case_dir / "runs"
    if not runs.is_dir():
        return
    recent = sorted(p for p in runs.glob("*.json") if p.stat().st_mtime >= started - 0.05)
    if not recent:
        return
    record = RunRecord.model_validate_json(recent[-1].read_text())
    row.stages_ran = [s.stage for s in record.stages if s.status == "ran"]
    row.stages_cached = [s.stage for s in record.stages if s.status == "cached"]
    row.failed_stage = next((s.stage for s in record.stages if s.status == "failed"), None)
