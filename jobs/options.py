"""Where jobs run: the executor and its settings, one declaration for every command that sends
jobs (`endopipe batch` its cases, a recording its windows). A dataclass read at start-up, like
`recording.options`: each field's metadata holds its help and lower bound."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from endopipe.pipeline.options import check_bounds


@dataclass(frozen=True)
class Execution:
    """The executor jobs are sent to, and how many run at once."""

    executor: str = field(
        default="local",
        metadata={
            "help": "Where jobs (a batch's cases, a recording's windows) run: local | slurm | ray."
        },
    )
    jobs: int | None = field(
        default=None,
        metadata={
            "min": 1,
            "help": "Jobs at once. local: worker processes (default: one a core, one thread each, "
            "one beside a GPU); slurm: array parallelism "
            "(default from the cluster config); ray: slots of a local cluster.",
        },
    )
    cluster_config: Path | None = field(
        default=None, metadata={"help": "Slurm / Ray settings (default configs/cluster.yaml)."}
    )
    ray_address: str | None = field(
        default=None,
        metadata={"help": "Ray cluster to join (auto, ray://host:10001); default: a local one."},
    )

    def __post_init__(self) -> None:
        from endopipe.pipeline.executors import EXECUTORS  # yaml, multiprocessing: when built

        check_bounds(self)
        if self.executor not in EXECUTORS:
            raise ValueError("executor", f"'{self.executor}' is not one of {', '.join(EXECUTORS)}")
