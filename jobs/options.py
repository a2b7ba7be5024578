"""Where jobs run: the executor and its settings, one model for every command that sends jobs
(`endopipe batch` its cases, a recording its windows)."""

from __future__ import annotations

from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field, field_validator

from endopipe.pipeline.executors import EXECUTORS


class Execution(BaseModel):
    """The executor jobs are sent to, and how many run at once."""

    model_config = ConfigDict(extra="forbid")

    executor: str = Field(
        "local",
        description="Where jobs (a batch's cases, a recording's windows) run: local | slurm | ray.",
    )
    jobs: int | None = Field(
        None,
        ge=1,
        description="Jobs at once. local: worker processes (default 1); slurm: array "
        "parallelism (default from the cluster config); ray: slots of a local cluster.",
    )
    cluster_config: Path | None = Field(
        None, description="Slurm / Ray settings (default configs/cluster.yaml)."
    )
    ray_address: str | None = Field(
        None, description="Ray cluster to join (auto, ray://host:10001); default: a local one."
    )

    @field_validator("executor")
    @classmethod
    def _known(cls, value: str) -> str:
        if value not in EXECUTORS:
            raise ValueError(f"'{value}' is not one of {', '.join(EXECUTORS)}")
        return value
