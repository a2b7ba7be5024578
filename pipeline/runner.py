"""Resolves the stage DAG for a case, decides run / skip / resume, holds the case lock."""

from __future__ import annotations

import datetime as dt
import importlib.metadata
import os
import platform
import shutil
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

import psutil
from filelock import FileLock, Timeout
from pydantic import BaseModel
from rich.console import Console

from endopipe.pipeline.cache import (
    KEY_CHANGED,
    Manifest,
    config_change,
    freshness,
    list_files,
    publish,
    stage_key,
    stale_temps,
    temp_dir_for,
)
from endopipe.pipeline.config import load_config, load_run_config, save_run_config
from endopipe.pipeline.errors import CaseLocked, EndopipeError
from endopipe.pipeline.stage import CaseInfo, Stage, StageConfig, StageContext, write_json

TRACKED_PACKAGES = (
    "endopipe",
    "torch",
    "numpy",
    "pycolmap",
    "opencv-python-headless",
    "av",
    "kornia",
    "open3d",
    "trimesh",
    "pymeshlab",
    "scikit-image",
    "scipy",
    "pydantic",
)


class PlannedStage(BaseModel):
    stage: str
    folder: str
    key: str
    fresh: bool
    reason: str
    action: Literal["run", "cached"]


class StageRecord(BaseModel):
    stage: str
    status: Literal["ran", "cached", "failed"]
    reason: str
    wall_s: float = 0.0
    cpu_s: float | None = None
    peak_rss_mb: float = 0.0
    summary: dict = {}


class RunRecord(BaseModel):
    case: str
    input: str
    started: str
    finished: str | None = None
    wall_s: float = 0.0
    ok: bool = False
    error: str | None = None
    host: str = platform.node()
    pid: int | None = None  # the process that ran it: with finished None, still running or killed
    running: str | None = None  # the stage running now (while finished is None)
    python: str = platform.python_version()
    packages: dict[str, str] = {}
    stages: list[StageRecord] = []


def read_runs(case_dir: Path, limit: int | None = None) -> list[RunRecord]:
    """The case's run records (<case>/runs/*.json), newest first; unreadable ones are skipped."""
    records = []
    for path in sorted((Path(case_dir) / "runs").glob("*.json"), reverse=True):
        if limit is not None and len(records) >= limit:
            break
        try:
            records.append(RunRecord.model_validate_json(path.read_text()))
        except ValueError:
            continue
    return records


def package_versions() -> dict[str, str]:
    out = {}
    for name in TRACKED_PACKAGES:
        try:
            out[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            continue
    return out


class PeakMemory:
    """Samples this process's resident memory in a thread: the peak while a stage runs."""

    def __init__(self, interval_s: float = 0.05) -> None:
        self.interval_s = interval_s
        self.peak = 0
        self._stop = threading.Event()
        self._proc = psutil.Process()

    def _loop(self) -> None:
        while not self._stop.is_set():
            self.peak = max(self.peak, self._proc.memory_info().rss)
            self._stop.wait(self.interval_s)

    def __enter__(self) -> PeakMemory:
        self.peak = self._proc.memory_info().rss
        self._thread = threading.Thread(target=self._loop, daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()
        self.peak = max(self.peak, self._proc.memory_info().rss)

    @property
    def peak_mb(self) -> float:
        return self.peak / 2**20


class Pipeline:
    """An ordered set of stages; the order is a topological order of `needs`."""

    def __init__(self, stages: Sequence[type[Stage]]) -> None:
        names = [s.name for s in stages]
        for s in stages:
            for need in s.needs:
                if need not in names[: names.index(s.name)]:
                    raise ValueError(f"stage {s.name} needs {need}, which must come before it")
        self.stages = list(stages)
        self.by_name = {s.name: s for s in stages}

    def folder_name(self, name: str) -> str:
        return f"{self.index(name) + 1:02d}_{name}"

    def folders(self, case_dir: Path) -> dict[str, Path]:
        """Each stage's published folder in `case_dir` (present or not), by stage name."""
        return {s.name: self.folder(case_dir, s.name) for s in self.stages}

    def folder(self, case_dir: Path, name: str) -> Path:
        """Where stage `name` publishes in `case_dir`: commands ask here, never spell it."""
        return Path(case_dir) / self.folder_name(name)

    def manifest(self, case_dir: Path, name: str) -> Manifest | None:
        """Stage `name`'s manifest in `case_dir` (its summary, times, memory), None if absent."""
        return Manifest.load(self.folder(case_dir, name))

    def view(self, case_dir: Path, name: str) -> Any:
        """Stage `name`'s own typed view of its published folder in `case_dir`."""
        return self.by_name[name].view(self.folder(case_dir, name))

    def index(self, name: str) -> int:
        if name not in self.by_name:
            raise EndopipeError(f"unknown stage '{name}'; stages: {', '.join(self.by_name)}")
        return [s.name for s in self.stages].index(name)

    def downstream(self, name: str) -> set[str]:
        out = {name}
        for s in self.stages:
            if any(n in out for n in s.needs):
                out.add(s.name)
        return out

    def ancestors(self, name: str) -> set[str]:
        out = {name}
        for s in reversed(self.stages):
            if s.name in out:
                out.update(s.needs)
        return out

    def selection(self, until: str | None) -> list[type[Stage]]:
        if until is None:
            return self.stages
        keep = self.ancestors(until)
        return [s for s in self.stages if s.name in keep]

    def plan(
        self,
        case_dir: Path,
        case: CaseInfo,
        configs: dict[str, StageConfig],
        until: str | None = None,
        from_stage: str | None = None,
        force: bool = False,
    ) -> list[PlannedStage]:
        forced = set(self.by_name) if force else set()
        if from_stage is not None:
            forced |= self.downstream(from_stage) if from_stage in self.by_name else set()
            self.index(from_stage)
        keys: dict[str, str] = {}
        dirty: set[str] = set()
        causes: dict[str, list[str]] = {}  # stage -> the stages whose change made its key new
        plan = []
        for stage in self.selection(until):
            cfg = configs[stage.name].model_dump(mode="json")
            upstream = {n: keys[n] for n in stage.needs}
            key = stage_key(
                stage.name, stage.version, cfg, upstream, None if stage.needs else case.input_digest
            )
            keys[stage.name] = key
            folder = case_dir / self.folder_name(stage.name)
            fresh, reason = freshness(folder, key)
            if reason == KEY_CHANGED:
                reason, causes[stage.name] = _why_changed(folder, stage, cfg, upstream, causes)
            if stage.name in forced:
                fresh, reason = False, "forced" if force else f"--from {from_stage}"
            elif fresh and any(n in dirty for n in stage.needs):
                rerun = ", ".join(n for n in stage.needs if n in dirty)
                fresh, reason = False, f"upstream {rerun} re-runs"
            if not fresh:
                dirty.add(stage.name)
            plan.append(
                PlannedStage(
                    stage=stage.name,
                    folder=folder.name,
                    key=key,
                    fresh=fresh,
                    reason=reason,
                    action="cached" if fresh else "run",
                )
            )
        return plan

    def run(
        self,
        case_dir: Path,
        configs: dict[str, StageConfig],
        *,
        until: str | None = None,
        from_stage: str | None = None,
        force: bool = False,
        dry_run: bool = False,
        wait_for_lock: bool = False,
        console: Console | None = None,
        quiet: bool = False,
    ) -> RunRecord:
        console = console or Console(stderr=True)
        case = CaseInfo.load(case_dir)
        lock = FileLock(str(case_dir / ".lock"))
        _acquire(lock, case.name, wait_for_lock, console)
        try:
            plan = self.plan(case_dir, case, configs, until, from_stage, force)
            if dry_run:
                return RunRecord(
                    case=case.name,
                    input=case.input,
                    started=_now(),
                    ok=True,
                    stages=[
                        StageRecord(
                            stage=p.stage, status="cached" if p.fresh else "ran", reason=p.reason
                        )
                        for p in plan
                    ],
                )
            save_run_config(case_dir, configs)
            return self._execute(case_dir, case, configs, plan, console, quiet)
        finally:
            lock.release()

    def _execute(
        self,
        case_dir: Path,
        case: CaseInfo,
        configs: dict[str, StageConfig],
        plan: list[PlannedStage],
        console: Console,
        quiet: bool,
    ) -> RunRecord:
        record = RunRecord(
            case=case.name,
            input=case.input,
            started=_now(),
            pid=os.getpid(),
            packages=package_versions(),
        )
        t_run = time.perf_counter()
        keys = {p.stage: p.key for p in plan}
        stamp = dt.datetime.now().strftime("%Y%m%dT%H%M%S_%f")
        record_path = case_dir / "runs" / f"{stamp}.json"
        try:
            for p in plan:
                stage_cls = self.by_name[p.stage]
                if p.fresh:
                    if not quiet:
                        console.print(f"[dim]· {p.stage:<11} cached[/dim]")
                    record.stages.append(
                        StageRecord(stage=p.stage, status="cached", reason="fresh")
                    )
                    continue
                if not quiet:
                    console.print(f"[bold cyan]▶ {p.stage:<11}[/bold cyan] running ({p.reason})")
                # the record so far (finished: None) is on disk while a stage runs: the report
                # stage shows its own run, status can see a run in progress
                record.wall_s = time.perf_counter() - t_run
                record.running = p.stage
                _save_record(record_path, record)
                rec = self._run_stage(case_dir, case, stage_cls, configs, p, keys, console, quiet)
                record.stages.append(rec)
                if not quiet:
                    console.print(
                        f"[green]✓ {p.stage:<11}[/green] {rec.wall_s:.1f} s, "
                        f"peak {rec.peak_rss_mb:.0f} MB"
                    )
            record.ok = True
        except BaseException as e:
            failed = next(
                (p.stage for p in plan if p.stage not in {r.stage for r in record.stages}), None
            )
            if failed is not None:
                reason = str(e).splitlines()[0] if str(e) else type(e).__name__
                record.stages.append(StageRecord(stage=failed, status="failed", reason=reason))
            record.error = f"{type(e).__name__}: {e}"
            raise
        finally:
            record.finished = _now()
            record.running = None
            record.wall_s = time.perf_counter() - t_run
            _save_record(record_path, record)
        return record

    def _run_stage(
        self,
        case_dir: Path,
        case: CaseInfo,
        stage_cls: type[Stage],
        configs: dict[str, StageConfig],
        p: PlannedStage,
        keys: dict[str, str],
        console: Console,
        quiet: bool,
    ) -> StageRecord:
        stage = stage_cls()  # the stage itself (a declared one is imported here)
        config = configs[stage_cls.name]
        if not isinstance(config, type(stage).Config):
            raise TypeError(
                f"stage {stage_cls.name} was given a {type(config).__name__}; it takes its "
                f"Config, {type(stage).Config.__name__}"
            )
        final = case_dir / p.folder
        tmp = temp_dir_for(final, p.key)
        for stale in stale_temps(final, keep=tmp):
            shutil.rmtree(stale, ignore_errors=True)
        if tmp.exists() and not stage_cls.resumable:
            shutil.rmtree(tmp)
        tmp.mkdir(parents=True, exist_ok=True)
        ctx = StageContext(
            case_dir=case_dir,
            out=tmp,
            config=config,
            case=case,
            inputs={n: case_dir / self.folder_name(n) for n in stage_cls.needs},
            views={n: self.by_name[n].View for n in stage_cls.needs},
            console=console,
            quiet=quiet,
        )
        started = time.time()
        t0, cpu0 = time.perf_counter(), time.process_time()
        try:
            with PeakMemory() as mem:
                summary = stage.run(ctx)
            check_summary(type(stage), summary)
        except BaseException:
            if not stage_cls.resumable:
                shutil.rmtree(tmp, ignore_errors=True)
            raise
        wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
        manifest = Manifest(
            stage=stage_cls.name,
            key=p.key,
            version=stage_cls.version,
            config=configs[stage_cls.name].model_dump(mode="json"),
            upstream={n: keys[n] for n in stage_cls.needs},
            started=started,
            finished=time.time(),
            wall_s=wall,
            cpu_s=cpu,
            peak_rss_mb=mem.peak_mb,
            summary=summary.model_dump(mode="json"),
            files=list_files(tmp),
        )
        publish(tmp, final, manifest)
        return StageRecord(
            stage=stage_cls.name,
            status="ran",
            reason=p.reason,
            wall_s=wall,
            cpu_s=cpu,
            peak_rss_mb=mem.peak_mb,
            summary=manifest.summary,
        )

    def status(
        self, case_dir: Path, configs: dict[str, StageConfig] | None = None
    ) -> list[PlannedStage]:
        """Each stage's state against `configs` ("would this config re-run?"), by default against
        the configuration the case was last run with."""
        if configs is None:
            configs = self.recorded_configs(case_dir)
        return self.plan(case_dir, CaseInfo.load(case_dir), configs)

    def recorded_configs(self, case_dir: Path) -> dict[str, StageConfig]:
        """The last run's configuration (<case>/config.yaml); for a case run before it was
        recorded, each stage's own config from its manifest, defaults where none ran."""
        recorded = load_run_config(self.stages, case_dir)
        if recorded is not None:
            return recorded
        configs = load_config(self.stages, use_default_file=False)
        for stage in self.stages:
            manifest = self.manifest(case_dir, stage.name)
            if manifest is not None:
                try:
                    configs[stage.name] = stage.Config.model_validate(manifest.config)
                except ValueError:  # written by another version: judge against the defaults
                    pass
        return configs

    def in_progress(self, case_dir: Path) -> RunRecord | None:
        """The run working on this case now (its record: pid, host, the stage running), if any.
        A record left unfinished by a killed process does not count."""
        runs = read_runs(case_dir, limit=1)
        if not runs or runs[0].finished is not None or runs[0].pid is None:
            return None
        run = runs[0]
        if run.host == platform.node() and not _alive(run.pid, run.started):
            return None
        return run

    def clean(self, case_dir: Path, stage: str | None) -> list[str]:
        names = [s.name for s in self.stages] if stage is None else sorted(self.downstream(stage))
        removed = []
        for name in names:
            final = case_dir / self.folder_name(name)
            for path in [final, *stale_temps(final, keep=None)]:
                if path.exists():
                    shutil.rmtree(path)
                    removed.append(path.name)
        return removed


def check_summary(stage: type[Stage], summary: object) -> None:
    """`run` returned the stage's own `Summary`: anything else would land in the manifest as a
    shape its view cannot read back."""
    if not isinstance(summary, stage.Summary):
        raise TypeError(
            f"stage {stage.name}: run returned {type(summary).__name__}, not its Summary "
            f"{stage.Summary.__name__}; nothing was published"
        )


def _save_record(path: Path, record: RunRecord) -> None:
    """Write the run record whole (temporary file, then rename): a reader never sees half."""
    path.parent.mkdir(exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    write_json(tmp, record.model_dump(mode="json"))
    os.replace(tmp, path)


def _alive(pid: int, started: str) -> bool:
    """The process `pid` exists and is the one that started at `started` (not a reused pid)."""
    try:
        created = psutil.Process(pid).create_time()
    except psutil.Error:
        return False
    return created <= dt.datetime.fromisoformat(started).timestamp() + 1


def _why_changed(
    folder: Path,
    stage: type[Stage],
    config: dict,
    upstream: dict[str, str],
    causes: dict[str, list[str]],
) -> tuple[str, list[str]]:
    """Why a stage's key is new, and the stages where the change began: its own setting
    (`nerf.train.steps 600 -> 1500`) or the upstream stage that changed first (`upstream
    ingest changed`, not every stage between)."""
    manifest = Manifest.load(folder)
    if manifest is None:
        return KEY_CHANGED, [stage.name]
    own = config_change(manifest, stage.version, config)
    if own is not None:
        return own, [stage.name]
    moved = [n for n in upstream if manifest.upstream.get(n) != upstream[n]]
    if not moved:
        return ("input changed" if not upstream else KEY_CHANGED), [stage.name]
    roots = list(dict.fromkeys(r for n in moved for r in causes.get(n, [n])))
    return f"upstream {', '.join(roots)} changed", roots


def _acquire(lock: FileLock, case: str, wait: bool, console: Console) -> None:
    """The case's lock; when another run holds it, fail in one line or, with --wait, say
    that we wait (a silent wait looks like a hang)."""
    try:
        lock.acquire(timeout=0)
        return
    except Timeout:
        if not wait:
            raise CaseLocked(
                f"another endopipe run is processing case '{case}'; wait for it to finish, "
                "or pass --wait to queue behind it"
            ) from None
    console.print(
        f"waiting for the other endopipe run on case '{case}' to finish "
        "(`endopipe status` shows it; Ctrl-C stops waiting)",
        markup=False,
        highlight=False,
    )
    lock.acquire(timeout=-1)


def _now() -> str:
    return dt.datetime.now().isoformat(timespec="seconds")


def ensure_writable(path: Path) -> None:
    """Fail early, in one line, when a workdir cannot hold a case."""
    try:
        path.mkdir(parents=True, exist_ok=True)
        probe = path / f".endopipe-write-test-{os.getpid()}"
        probe.write_text("")
        probe.unlink()
    except OSError as e:
        raise EndopipeError(
            f"cannot write to workdir {path}: {e.strerror or e}; "
            "pass --workdir DIR with a writable folder"
        ) from None
