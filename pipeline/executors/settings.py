"""configs/cluster.yaml: the Slurm and Ray resources a job asks for."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from endopipe.pipeline.config import CONFIG_DIR
from endopipe.pipeline.errors import ConfigError

CLUSTER_CONFIG = CONFIG_DIR / "cluster.yaml"


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
