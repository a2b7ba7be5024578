"""Where the cases of a batch run: one seam, `concurrent.futures.Executor`, three engines.

- `local` (default): `--jobs N` worker processes (spawn) on this machine, each limited to
  cores // N threads so that N cases never oversubscribe the CPU.
- `slurm`: one Slurm job per case through submitit, submitted as one job array; resources from
  configs/cluster.yaml (`slurm:`); `cluster: local` runs the same jobs as local processes
  through submitit's LocalExecutor (no Slurm needed), `cluster: debug` in this process.
- `ray`: one Ray task per case, on an existing cluster (`--ray-address`) or a local one.

The function a batch runs is top-level and picklable, takes a `CaseTask` and returns a
`CaseRow` (it never raises). This module also gathers the rows into batch.csv and batch.html.
It knows nothing of endoscopy: a case is a name, an input path and a set of stage summaries.
"""

from __future__ import annotations

import contextlib
import csv
import html
import math
import multiprocessing
import os
import platform
import shutil
import statistics
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Executor, Future, ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from endopipe.pipeline.config import CONFIG_DIR
from endopipe.pipeline.errors import ConfigError, EndopipeError

EXECUTORS = ("local", "slurm", "ray")
CLUSTER_CONFIG = CONFIG_DIR / "cluster.yaml"
THREAD_VARS = (
    "OMP_NUM_THREADS",
    "MKL_NUM_THREADS",
    "OPENBLAS_NUM_THREADS",
    "NUMEXPR_NUM_THREADS",
    "VECLIB_MAXIMUM_THREADS",
)


# ---------------------------------------------------------------- what runs: tasks and rows


class CaseTask(BaseModel):
    """Everything one case needs, small and picklable (configs are resolved JSON)."""

    name: str
    input: str
    reader: str
    workdir: str
    configs: dict[str, dict[str, Any]]
    until: str | None = None
    threads: int | None = None
    check_only: bool = False  # only report whether every stage is already fresh


class CaseRow(BaseModel):
    """One line of batch.csv: how a case went. Built by the case function, never raised."""

    case: str
    status: Literal["ok", "failed", "pending"]
    reader: str
    gt_kind: str = ""  # exact | pseudo | "" (no ground truth)
    stages_ran: list[str] = []
    stages_cached: list[str] = []
    failed_stage: str | None = None
    reason: str = ""
    wall_s: float = 0.0  # this batch's time on the case, start to finish
    compute_s: float = 0.0  # sum of the stages' own wall times (from their manifests)
    peak_rss_mb: float = 0.0  # the largest stage peak (from their manifests)
    metrics: dict[str, float] = {}
    report: str | None = None  # report.html, relative to the workdir
    input: str = ""
    host: str = Field(default_factory=platform.node)


def one_line(e: BaseException | str, limit: int = 300) -> str:
    text = str(e).strip()
    line = next((ln.strip() for ln in text.splitlines() if ln.strip()), type(e).__name__)
    return line if len(line) <= limit else line[: limit - 1] + "…"


def numeric_leaves(data: Any, prefix: str = "") -> dict[str, float]:
    """Flatten a stage summary to its numbers: {"kept": 12, "dropped": {"blank": 1}} ->
    {"kept": 12.0, "dropped.blank": 1.0}. Booleans, strings and lists are left out."""
    out: dict[str, float] = {}
    if isinstance(data, dict):
        for k, v in data.items():
            out.update(numeric_leaves(v, f"{prefix}.{k}" if prefix else str(k)))
    elif isinstance(data, (int, float)) and not isinstance(data, bool) and prefix:
        if math.isfinite(float(data)):
            out[prefix] = float(data)
    return out


# ---------------------------------------------------------------- threads per worker


def available_cores() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - macOS
        return max(1, os.cpu_count() or 1)


def threads_per_job(jobs: int) -> int:
    return max(1, available_cores() // max(1, jobs))


def limit_threads(n: int) -> None:
    """Cap the math libraries of this process at n threads (env for those not yet loaded)."""
    for var in THREAD_VARS:
        os.environ[var] = str(n)
    if "torch" in sys.modules:
        sys.modules["torch"].set_num_threads(n)
    if "cv2" in sys.modules:
        sys.modules["cv2"].setNumThreads(n)


@contextlib.contextmanager
def thread_env(n: int) -> Iterator[None]:
    """Child processes started inside the block inherit an n-thread limit from birth."""
    saved = {v: os.environ.get(v) for v in THREAD_VARS}
    for var in THREAD_VARS:
        os.environ[var] = str(n)
    try:
        yield
    finally:
        for var, value in saved.items():
            if value is None:
                os.environ.pop(var, None)
            else:
                os.environ[var] = value


# ---------------------------------------------------------------- configs/cluster.yaml


class SlurmSettings(BaseModel):
    model_config = ConfigDict(extra="forbid")

    cluster: Literal["auto", "slurm", "local", "debug"] = "auto"
    partition: str | None = None
    account: str | None = None
    qos: str | None = None
    constraint: str | None = None
    gpus_per_node: int = Field(1, ge=0)
    cpus_per_task: int = Field(8, ge=1)
    mem_gb: float = Field(32, gt=0)
    timeout_min: int = Field(240, ge=1)
    array_parallelism: int = Field(32, ge=1)
    setup: list[str] = []
    additional_parameters: dict[str, Any] = {}
    poll_s: float = Field(15.0, gt=0)


class RaySettings(BaseModel):
    model_config = ConfigDict(extra="forbid")

    address: str | None = None
    num_gpus: float = Field(1, ge=0)
    num_cpus: float = Field(8, gt=0)
    max_retries: int = Field(0, ge=0)
    runtime_env: dict[str, Any] = {}


class ClusterConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")

    slurm: SlurmSettings = SlurmSettings()
    ray: RaySettings = RaySettings()


def load_cluster_config(path: Path | None = None) -> ClusterConfig:
    path = Path(path) if path is not None else CLUSTER_CONFIG
    if not path.is_file():
        if path == CLUSTER_CONFIG:
            return ClusterConfig()
        raise ConfigError(f"cluster config not found: {path}")
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError:
        raise ConfigError(f"cluster config {path} is not valid YAML") from None
    try:
        return ClusterConfig.model_validate(data)
    except ValidationError as e:
        err = e.errors()[0]
        where = ".".join(str(p) for p in err["loc"])
        raise ConfigError(f"{path}: {where}: {err['msg']} (got {err.get('input')!r})") from None


# ---------------------------------------------------------------- the engines


def local_executor(jobs: int, threads: int) -> ProcessPoolExecutor:
    return ProcessPoolExecutor(
        max_workers=max(1, jobs),
        mp_context=multiprocessing.get_context("spawn"),
        initializer=limit_threads,
        initargs=(threads,),
    )


class SubmititExecutor(Executor):
    """submitit jobs behind the Executor seam: futures resolve as a watcher sees jobs finish.

    On Slurm every `submit_many` becomes one job array (Slurm limits how many run at once);
    the local and debug clusters start at most `max_in_flight` jobs at a time.
    """

    def __init__(self, settings: SlurmSettings, workdir: Path, jobs: int | None) -> None:
        try:
            import submitit
        except ImportError:
            raise EndopipeError(
                "the slurm executor needs submitit: pip install 'endopipe[slurm]'"
            ) from None
        cluster = settings.cluster
        if cluster == "auto":
            if shutil.which("sbatch") is None:
                raise EndopipeError(
                    "no Slurm on this machine (sbatch not found); run the batch from a Slurm "
                    "login node, or set slurm.cluster: local in the cluster config to try it here"
                )
            cluster = "slurm"
        self.cluster = cluster
        self.log_dir = Path(workdir).resolve() / ".batch" / "slurm"
        self.threads = settings.cpus_per_task if cluster == "slurm" else threads_per_job(jobs or 1)
        self._ex = submitit.AutoExecutor(folder=self.log_dir / "%j", cluster=cluster)
        params: dict[str, Any] = {
            "name": "endopipe",
            "timeout_min": settings.timeout_min,
            "gpus_per_node": settings.gpus_per_node,
            "cpus_per_task": settings.cpus_per_task,
            "mem_gb": settings.mem_gb,
        }
        if cluster == "slurm":
            exports = [f"export {v}={settings.cpus_per_task}" for v in THREAD_VARS]
            params.update(
                slurm_partition=settings.partition,
                slurm_account=settings.account,
                slurm_qos=settings.qos,
                slurm_constraint=settings.constraint,
                slurm_array_parallelism=jobs or settings.array_parallelism,
                slurm_setup=[*exports, *settings.setup],
                slurm_additional_parameters=settings.additional_parameters or None,
            )
        self._ex.update_parameters(**{k: v for k, v in params.items() if v is not None})
        self.max_in_flight = None if cluster == "slurm" else max(1, jobs or 1)
        self.poll_s = settings.poll_s if cluster == "slurm" else 0.2
        self._lock = threading.Lock()
        self._queued: list[tuple[Future, Callable, tuple]] = []
        self._running: list[tuple[Future, Any]] = []
        self._stop = threading.Event()
        self._watcher: threading.Thread | None = None

    def submit(self, fn: Callable, /, *args: Any, **kwargs: Any) -> Future:
        if kwargs:
            raise TypeError("SubmititExecutor.submit takes positional arguments only")
        return self.submit_many(fn, [args])[0]

    def submit_many(self, fn: Callable, arg_tuples: Sequence[tuple]) -> list[Future]:
        futures = [Future() for _ in arg_tuples]
        with self._lock:
            if self.max_in_flight is None:
                try:
                    with self._ex.batch():  # one sbatch --array for all of them
                        jobs = [self._ex.submit(fn, *args) for args in arg_tuples]
                except Exception as e:
                    raise EndopipeError(
                        f"Slurm refused the batch's job array ({one_line(e)}); check the slurm "
                        "section of the cluster config"
                    ) from None
                self._running.extend(zip(futures, jobs, strict=True))
                for f in futures:
                    f.set_running_or_notify_cancel()
            else:
                self._queued.extend(
                    (f, fn, tuple(args)) for f, args in zip(futures, arg_tuples, strict=True)
                )
        if self._watcher is None:
            self._watcher = threading.Thread(target=self._watch, daemon=True)
            self._watcher.start()
        return futures

    def _watch(self) -> None:
        while not self._stop.is_set():
            with self._lock:
                while self._queued and len(self._running) < (self.max_in_flight or 1 << 30):
                    future, fn, args = self._queued.pop(0)
                    if not future.set_running_or_notify_cancel():
                        continue
                    try:
                        self._running.append((future, self._ex.submit(fn, *args)))
                    except Exception as e:  # submission itself failed
                        future.set_exception(e)
                still = []
                for future, job in self._running:
                    try:  # a debug job runs (in this thread) when its result is asked for
                        done = self.cluster == "debug" or job.done()
                    except Exception as e:
                        future.set_exception(e)
                        continue
                    if not done:
                        still.append((future, job))
                        continue
                    try:
                        future.set_result(job.result())
                    except Exception as e:
                        future.set_exception(e)
                self._running = still
                idle = not self._running and not self._queued
            if idle:
                self._stop.wait(0.05)
            else:
                self._stop.wait(self.poll_s)

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        if cancel_futures:
            with self._lock:
                for future, _, _ in self._queued:
                    future.cancel()
                self._queued.clear()
                for _, job in self._running:
                    with contextlib.suppress(Exception):
                        job.cancel(check=False)
        if wait and not cancel_futures:
            while True:
                with self._lock:
                    if not self._running and not self._queued:
                        break
                time.sleep(0.1)
        self._stop.set()
        if self._watcher is not None and wait:
            self._watcher.join(timeout=5)


class RayExecutor(Executor):
    """One Ray task per case. Connects to `address` (or RAY_ADDRESS), else starts a local
    cluster with `jobs` CPU slots, one per task, and shuts it down afterwards."""

    def __init__(
        self,
        settings: RaySettings,
        address: str | None,
        jobs: int | None,
        note: Callable[[str], None] = print,
    ) -> None:
        try:
            import ray
        except ImportError:
            raise EndopipeError("the ray executor needs ray: pip install 'endopipe[ray]'") from None
        import logging

        self._ray = ray
        address = address or settings.address or os.environ.get("RAY_ADDRESS")
        self.local = not address
        runtime_env = settings.runtime_env or None
        self._started = False
        if self.local:
            slots = max(1, jobs or 1)
            self.threads = threads_per_job(slots)
            if not ray.is_initialized():
                ray.init(
                    num_cpus=slots,
                    include_dashboard=False,
                    log_to_driver=False,
                    logging_level=logging.WARNING,
                    runtime_env=runtime_env,
                )
                self._started = True
            num_cpus: float = 1
        else:
            try:
                ray.init(
                    address=address,
                    log_to_driver=False,
                    logging_level=logging.WARNING,
                    runtime_env=runtime_env,
                    ignore_reinit_error=True,
                )
            except (ConnectionError, RuntimeError, ValueError) as e:
                raise EndopipeError(
                    f"cannot connect to the Ray cluster at {address} ({one_line(e)}); start it "
                    "with `ray start --head` or check --ray-address"
                ) from None
            num_cpus = settings.num_cpus
            self.threads = max(1, int(num_cpus))
        num_gpus = settings.num_gpus
        have = ray.cluster_resources().get("GPU", 0)
        if num_gpus > have:
            if self.local:
                if num_gpus:
                    note(f"the local Ray cluster has {have:g} GPU(s): tasks run without a GPU")
                num_gpus = 0
            else:
                note(f"the Ray cluster reports {have:g} GPU(s); tasks ask for {num_gpus:g} each")
        self.options = {
            "num_cpus": num_cpus,
            "num_gpus": num_gpus,
            "max_retries": settings.max_retries,
        }
        self._refs: list[Any] = []
        self._remote: dict[Callable, Any] = {}

    def submit(self, fn: Callable, /, *args: Any, **kwargs: Any) -> Future:
        if fn not in self._remote:
            self._remote[fn] = self._ray.remote(**self.options)(fn)
        ref = self._remote[fn].remote(*args, **kwargs)
        self._refs.append(ref)
        return ref.future()

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        if cancel_futures:
            for ref in self._refs:
                with contextlib.suppress(Exception):
                    self._ray.cancel(ref, force=True)
        if self._started and self._ray.is_initialized():
            self._ray.shutdown()


def make_executor(
    kind: str,
    *,
    jobs: int | None,
    workdir: Path,
    cluster: ClusterConfig,
    ray_address: str | None = None,
    note: Callable[[str], None] = print,
) -> tuple[Executor, int]:
    """(executor, threads each case may use)."""
    if kind == "local":
        threads = threads_per_job(jobs or 1)
        return local_executor(jobs or 1, threads), threads
    if kind == "slurm":
        ex = SubmititExecutor(cluster.slurm, workdir, jobs)
        return ex, ex.threads
    if kind == "ray":
        rex = RayExecutor(cluster.ray, ray_address, jobs, note)
        return rex, rex.threads
    raise EndopipeError(f"unknown executor '{kind}'; executors: {', '.join(EXECUTORS)}")


# ---------------------------------------------------------------- the batch driver


def run_cases(
    kind: str,
    fn: Callable[[CaseTask], CaseRow],
    tasks: Sequence[CaseTask],
    *,
    jobs: int | None,
    workdir: Path,
    cluster: ClusterConfig,
    ray_address: str | None = None,
    on_row: Callable[[CaseRow], None] = lambda row: None,
    note: Callable[[str], None] = print,
) -> list[CaseRow]:
    """Run `fn` on every task with executor `kind`; one row per task, in task order.

    Each case is first checked here (`check_only`): only those with work left are sent to the
    executor, which is not even started when there are none.

    A case whose job dies (a crash, a Slurm job killed, a Ray task lost) gets a failed row
    with the reason; the others carry on. With the local executor a crashed worker process
    breaks the whole pool, so the cases it took down are re-run one at a time, each in a
    fresh process, to tell the culprit from the bystanders.
    """
    rows: dict[str, CaseRow] = {}
    todo = list(tasks)
    if todo:
        # No job (nor worker process, nor cluster) for a case with nothing left to do, or
        # whose input cannot be used: a finished batch re-runs in seconds.
        for task in list(todo):
            row = fn(task.model_copy(update={"check_only": True}))
            if row.status != "pending":
                rows[task.name] = row
                todo.remove(task)
                on_row(row)
    if not todo:
        return [rows[t.name] for t in tasks]
    executor, threads = make_executor(
        kind, jobs=jobs, workdir=workdir, cluster=cluster, ray_address=ray_address, note=note
    )
    todo = [t.model_copy(update={"threads": threads}) for t in todo]
    crashed: list[CaseTask] = []
    with thread_env(threads):
        try:
            if hasattr(executor, "submit_many"):
                futures = executor.submit_many(fn, [(t,) for t in todo])
            else:
                futures = [executor.submit(fn, t) for t in todo]
            by_future = dict(zip(futures, todo, strict=True))
            for future in as_completed(by_future):
                task = by_future[future]
                try:
                    row = future.result()
                except BrokenProcessPool:
                    crashed.append(task)
                    continue
                except Exception as e:
                    row = failed_row(task, f"{kind} job failed: {one_line(e)}")
                rows[task.name] = row
                on_row(row)
        except BaseException:
            executor.shutdown(wait=False, cancel_futures=True)
            raise
        executor.shutdown(wait=True)
        for task in crashed:  # local only: isolate the case that killed its worker
            with local_executor(1, threads) as alone:
                try:
                    row = alone.submit(fn, task).result()
                except BrokenProcessPool:
                    row = failed_row(task, "its worker process died (a crash, or out of memory)")
            rows[task.name] = row
            on_row(row)
    return [rows[t.name] for t in tasks]


def failed_row(task: CaseTask, reason: str) -> CaseRow:
    return CaseRow(
        case=task.name, status="failed", reader=task.reader, reason=reason, input=task.input
    )


# ---------------------------------------------------------------- batch.csv and batch.html

FIXED_COLUMNS = (
    "case",
    "status",
    "reader",
    "gt_kind",
    "stages_ran",
    "stages_cached",
    "failed_stage",
    "reason",
    "wall_s",
    "compute_s",
    "peak_rss_mb",
)
NUMERIC_FIXED = ("wall_s", "compute_s", "peak_rss_mb")


def metric_columns(rows: Sequence[CaseRow]) -> list[str]:
    cols: dict[str, None] = {}
    for row in rows:
        cols.update(dict.fromkeys(row.metrics))
    return list(cols)


def _cell(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, list):
        return "+".join(value)
    if isinstance(value, float):
        return f"{value:.6g}"
    return str(value)


def row_values(row: CaseRow, metrics: Sequence[str]) -> dict[str, Any]:
    data = row.model_dump()
    out = {c: data[c] for c in FIXED_COLUMNS}
    out.update({m: row.metrics.get(m) for m in metrics})
    out["report"] = row.report
    out["input"] = row.input
    out["host"] = row.host
    return out


def write_csv(rows: Sequence[CaseRow], path: Path) -> Path:
    metrics = metric_columns(rows)
    columns = [*FIXED_COLUMNS, *metrics, "report", "input", "host"]
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(columns)
        for row in rows:
            values = row_values(row, metrics)
            writer.writerow([_cell(values[c]) for c in columns])
    tmp.replace(path)
    return path


def column_stats(rows: Sequence[CaseRow]) -> dict[str, tuple[float, float, int]]:
    """(mean, median, count) of every numeric column over the cases that have it."""
    out = {}
    for col in [*NUMERIC_FIXED, *metric_columns(rows)]:
        values = []
        for row in rows:
            v = getattr(row, col) if col in NUMERIC_FIXED else row.metrics.get(col)
            if v is not None and (col not in NUMERIC_FIXED or row.status == "ok"):
                values.append(float(v))
        if values:
            out[col] = (statistics.fmean(values), statistics.median(values), len(values))
    return out


_CSS = """
body{font:14px system-ui,sans-serif;margin:24px;color:#222}
table{border-collapse:collapse;font-size:13px}
th,td{border:1px solid #ccc;padding:3px 7px;text-align:right;white-space:nowrap}
th{background:#f0f0f0;position:sticky;top:0}
td.t{text-align:left}
td.reason{text-align:left;white-space:normal;max-width:420px}
tr.failed td{background:#fdecea}
tr.stat td{background:#eef4fb;font-weight:600}
.ok{color:#1a7f37}.failed{color:#b42318}.pseudo{color:#9a6700}
"""


def write_html(rows: Sequence[CaseRow], path: Path, title: str = "endopipe batch") -> Path:
    """A self-contained table: one row per case (linked to its report), then mean and median."""
    metrics = metric_columns(rows)
    columns = [*FIXED_COLUMNS, *metrics]
    stats = column_stats(rows)
    text_cols = {"case", "status", "reader", "gt_kind", "stages_ran", "stages_cached"}
    text_cols.add("failed_stage")
    esc = html.escape
    out = [
        "<!doctype html><html><head><meta charset='utf-8'>",
        f"<title>{esc(title)}</title><style>{_CSS}</style></head><body>",
        f"<h1>{esc(title)}</h1>",
    ]
    n_ok = sum(r.status == "ok" for r in rows)
    out.append(
        f"<p>{len(rows)} case(s): {n_ok} ok, {len(rows) - n_ok} failed. "
        f"Written {esc(time.strftime('%Y-%m-%d %H:%M:%S'))}. "
        "<span class='pseudo'>gt_kind pseudo</span>: the ground truth is derived (e.g. Hamlyn's "
        "stereo depth), not measured; treat its metrics as indicative.</p>"
    )
    out.append("<table><thead><tr>")
    out += [f"<th>{esc(c)}</th>" for c in columns]
    out.append("</tr></thead><tbody>")
    for row in rows:
        values = row_values(row, metrics)
        out.append(f"<tr class='{esc(row.status)}'>")
        for c in columns:
            cell = esc(_cell(values[c]))
            if c == "case" and row.report:
                rel = os.path.relpath(Path(path).parent / row.report, Path(path).parent)
                cell = f"<a href='{esc(Path(rel).as_posix())}'>{cell}</a>"
            elif c == "status":
                cell = f"<span class='{esc(row.status)}'>{cell}</span>"
            elif c == "gt_kind" and row.gt_kind == "pseudo":
                cell = f"<span class='pseudo'>{cell}</span>"
            klass = "reason" if c == "reason" else ("t" if c in text_cols else "")
            out.append(f"<td class='{klass}'>{cell}</td>" if klass else f"<td>{cell}</td>")
        out.append("</tr>")
    out.append("</tbody><tfoot>")
    for label, i in (("mean", 0), ("median", 1)):
        out.append(f"<tr class='stat'><td class='t'>{label}</td>")
        for c in columns[1:]:
            s = stats.get(c)
            out.append(f"<td>{_cell(s[i])}</td>" if s else "<td></td>")
        out.append("</tr>")
    out.append("</tfoot></table></body></html>\n")
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text("".join(out))
    tmp.replace(path)
    return path
