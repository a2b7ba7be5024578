"""The base of every section of the nerf config, shared by the modules that hold them."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict


class ConfigSection(BaseModel):
    """A config section: an unknown key is a typo to refuse, and `--set` values are checked."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True)
