"""Ray tasks behind the Executor seam, on an existing cluster or a local one."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable
from concurrent.futures import Executor, Future
from typing import Any

from endopipe.pipeline.errors import EndopipeError, one_line
from endopipe.pipeline.executors.settings import RaySettings
from endopipe.pipeline.executors.threads import threads_per_job


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
