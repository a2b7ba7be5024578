"""configs/: default.yaml is the code's defaults; every preset loads."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from endopipe.cli import build_pipeline
from endopipe.pipeline.config import (
    CONFIG_DIR,
    default_yaml,
    describe_fields,
    load_config,
    preset_names,
)


def test_default_yaml_matches_the_code() -> None:
    pipe = build_pipeline()
    text = (CONFIG_DIR / "default.yaml").read_text()
    assert text == default_yaml(pipe.stages) + "\n", "regenerate: endopipe stages --yaml"
    with_file = load_config(pipe.stages, use_default_file=True)
    without = load_config(pipe.stages, use_default_file=False)
    assert {k: v.model_dump() for k, v in with_file.items()} == {
        k: v.model_dump() for k, v in without.items()
    }


@pytest.mark.parametrize("preset", preset_names())
def test_every_preset_validates(preset: str) -> None:
    load_config(build_pipeline().stages, [preset])


def test_stages_lists_every_leaf_key_with_type_default_and_help() -> None:
    env = {**os.environ, "COLUMNS": "80"}  # as in a narrow terminal or a pipe: nothing cut
    cmd = [sys.executable, "-m", "endopipe", "stages"]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=60, env=env)
    assert done.returncode == 0, done.stderr
    text = done.stdout
    assert "PydanticUndefined" not in text and "…" not in text
    assert "nerf.train.steps = 1500  [int]" in text
    assert "ingest.fov.enabled = true  [bool]" in text
    assert "nerf.field.tensorf.upsample_at = [0.15, 0.3, 0.45]  [list[float]]" in text
    assert "ingest.max_frames = null  [int | None]" in text
    leaves = [
        line.split(":")[0].strip()
        for line in (CONFIG_DIR / "default.yaml").read_text().splitlines()
        if line.strip() and not line.lstrip().startswith("#") and not line.rstrip().endswith(":")
    ]
    keys = [line for line in text.splitlines() if line.startswith("  ") and line[2] != " "]
    listed = [line.split(" = ")[0].strip() for line in keys if " = " in line]
    assert len(listed) == len(leaves) == len(set(listed))  # every leaf key, each once
    for stage in build_pipeline().stages:
        for key, _, _, help_text in describe_fields(stage.Config):
            line = _index(text, f"{stage.name}.{key} = ")
            assert help_text in text.splitlines()[line + 1]


def _index(text: str, start: str) -> int:
    return next(i for i, line in enumerate(text.splitlines()) if line.strip().startswith(start))
