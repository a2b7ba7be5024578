"""Where jobs run: one seam, `concurrent.futures.Executor`, three engines.

- `local` (default): `--jobs N` worker processes (spawn) on this machine, each limited to
  cores // N threads so that N jobs never oversubscribe the CPU.
- `slurm`: one Slurm job per call through submitit, submitted as one job array; resources from
  configs/cluster.yaml (`slurm:`); `cluster: local` runs the same jobs as local processes
  through submitit's LocalExecutor (no Slurm needed), `cluster: debug` in this process.
- `ray`: one Ray task per call, on an existing cluster (`--ray-address`) or a local one.

The engines run any top-level, picklable function; what a job is (a case of `endopipe batch`)
and how results are gathered belong to the command that submits them.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Executor
from pathlib import Path

from endopipe.pipeline.errors import EndopipeError
from endopipe.pipeline.executors.local import local_executor
from endopipe.pipeline.executors.ray import RayExecutor
from endopipe.pipeline.executors.settings import (
    CLUSTER_CONFIG,
    ClusterConfig,
    RaySettings,
    SlurmSettings,
    load_cluster_config,
)
from endopipe.pipeline.executors.slurm import SubmititExecutor
from endopipe.pipeline.executors.threads import (
    THREAD_VARS,
    available_cores,
    limit_threads,
    local_jobs,
    thread_env,
    threads_per_job,
)

EXECUTORS = ("local", "slurm", "ray")

__all__ = [
    "CLUSTER_CONFIG",
    "EXECUTORS",
    "THREAD_VARS",
    "ClusterConfig",
    "RayExecutor",
    "RaySettings",
    "SlurmSettings",
    "SubmititExecutor",
    "available_cores",
    "limit_threads",
    "load_cluster_config",
    "local_executor",
    "local_jobs",
    "make_executor",
    "thread_env",
    "threads_per_job",
]


def make_executor(
    kind: str,
    *,
    jobs: int | None,
    workdir: Path,
    cluster: ClusterConfig,
    ray_address: str | None = None,
    note: Callable[[str], None] = print,
    tasks: int = 1,
) -> tuple[Executor, int]:
    """(executor, threads each job may use) for `kind`: local | slurm | ray. `tasks`: how many
    jobs there are to run (a local executor without `jobs` runs up to one a core)."""
    if kind == "local":
        if jobs is None:
            jobs = local_jobs(tasks)
            if jobs > 1:
                note(f"{jobs} jobs at once, one thread each (--jobs N to choose)")
        threads = threads_per_job(jobs)
        return local_executor(jobs, threads), threads
    if kind == "slurm":
        ex = SubmititExecutor(cluster.slurm, workdir, jobs)
        return ex, ex.threads
    if kind == "ray":
        rex = RayExecutor(cluster.ray, ray_address, jobs, note)
        return rex, rex.threads
    raise EndopipeError(f"unknown executor '{kind}'; executors: {', '.join(EXECUTORS)}")
