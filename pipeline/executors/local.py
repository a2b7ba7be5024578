"""The default engine: worker processes on this machine (spawned, so no state is shared).

A worker outlives nothing: when the process that started it dies (SIGTERM, SIGKILL, a crash),
the worker ends too, instead of running on as an orphan that competes for the CPU and writes
into the cases a re-run is about to take over.
"""

from __future__ import annotations

import multiprocessing
import os
import threading
import time
from concurrent.futures import ProcessPoolExecutor

from endopipe.pipeline.executors.threads import limit_threads

PARENT_POLL_S = 1.0


def local_executor(jobs: int, threads: int) -> ProcessPoolExecutor:
    """A fresh worker for every case: a worker that ran a case held 1.4 GB more at its next
    one's start (a 3,000-frame recording's windows, one after another), so memory stays one
    case's, for the price of a process start (a few seconds) per case."""
    return ProcessPoolExecutor(
        max_workers=max(1, jobs),
        mp_context=multiprocessing.get_context("spawn"),
        initializer=start_worker,
        initargs=(threads, os.getpid()),
        max_tasks_per_child=1,
    )


def start_worker(threads: int, parent: int) -> None:
    """A worker's set-up: its thread limit, and a watch that ends it with its parent."""
    limit_threads(threads)
    watch = threading.Thread(target=_end_with_parent, args=(parent,), daemon=True)
    watch.start()


def _end_with_parent(parent: int) -> None:
    while os.getppid() == parent:
        time.sleep(PARENT_POLL_S)
    os._exit(1)  # orphaned: the run that wanted this work is gone
