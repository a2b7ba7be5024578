"""configs/: default.yaml is the code's defaults; every preset loads."""

from __future__ import annotations

import pytest

from endopipe.cli import build_pipeline
from endopipe.pipeline.config import CONFIG_DIR, default_yaml, load_config, preset_names


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
