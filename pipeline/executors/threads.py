"""Threads per job: N jobs on one machine share its cores instead of each taking them all."""

from __future__ import annotations

import contextlib
import os
import sys
import time
from collections.abc import Iterator

import psutil

THREAD_VARS = (
    "OMP_NUM_THREADS",
    "MKL_NUM_THREADS",
    "OPENBLAS_NUM_THREADS",
    "NUMEXPR_NUM_THREADS",
    "VECLIB_MAXIMUM_THREADS",
)


def available_cores() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - macOS
        return max(1, os.cpu_count() or 1)


def threads_per_job(jobs: int) -> int:
    return max(1, available_cores() // max(1, jobs))


#: Memory a local job may take at its peak (a window's NeRF and depth stages: 1.5-1.7 GB on the
#: shared C3VD preview), with room for the larger cases.
JOB_MEMORY_BYTES = 4 << 30


def local_jobs(tasks: int) -> int:
    """How many local jobs run at once when the user did not say: one a core (each on one
    thread), at most the tasks and what the free memory holds; one beside a GPU, which the
    jobs would share. On two cores two one-thread NeRF trainings step as fast as one alone
    (C3VD at step 1200: 104-107 ms a step each, against 97-123 ms for one on one or two
    threads): a training leaves the second core idle."""
    if tasks <= 1 or _has_gpu():
        return 1
    memory = int(psutil.virtual_memory().available // JOB_MEMORY_BYTES)
    return max(1, min(tasks, available_cores(), memory))


def _has_gpu() -> bool:
    import torch  # the jobs' own stages load it anyway

    return bool(torch.cuda.is_available())


def job_thread_limit() -> int | None:
    """The thread limit this process was started or set up with (`limit_threads`,
    `thread_env`), None when it has none: a stage that picks its own thread count stays under
    it, so that jobs sharing the machine never oversubscribe it."""
    value = os.environ.get(THREAD_VARS[0], "")
    return int(value) if value.isdigit() and int(value) > 0 else None


def auto_threads(window_s: float = 0.5) -> int:
    """CPU threads for torch: the cores not busy with other processes, at least 1, at most
    this job's share (`job_thread_limit`), even while the jobs beside it idle.

    OpenMP threads that must share a core with other processes spin at every barrier: on a
    loaded 2-core machine two threads ran a step ~10x slower than one. Busy is measured over
    `window_s` now, less this process's own use: the load average would count the poses stage
    that just ran in this very process as another job."""
    cores = available_cores()
    me = psutil.Process()
    me.cpu_percent(None)
    psutil.cpu_percent(None)
    time.sleep(window_s)
    others = psutil.cpu_percent(None) / 100.0 * psutil.cpu_count() - me.cpu_percent(None) / 100.0
    free = int(min(cores, max(1, round(cores - max(others, 0.0)))))
    limit = job_thread_limit()
    return min(free, limit) if limit is not None else free


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
