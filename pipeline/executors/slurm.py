"""Slurm through submitit, behind the Executor seam (or submitit's local and debug clusters)."""

from __future__ import annotations

import contextlib
import shutil
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Executor, Future
from pathlib import Path
from typing import Any

from endopipe.pipeline.errors import EndopipeError, one_line
from endopipe.pipeline.executors.settings import SlurmSettings
from endopipe.pipeline.executors.threads import THREAD_VARS, threads_per_job


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
