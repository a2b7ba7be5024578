"""The default engine: worker processes on this machine (spawned, so no state is shared)."""

from __future__ import annotations

import multiprocessing
from concurrent.futures import ProcessPoolExecutor

from endopipe.pipeline.executors.threads import limit_threads


def local_executor(jobs: int, threads: int) -> ProcessPoolExecutor:
    return ProcessPoolExecutor(
        max_workers=max(1, jobs),
        mp_context=multiprocessing.get_context("spawn"),
        initializer=limit_threads,
        initargs=(threads,),
    )
