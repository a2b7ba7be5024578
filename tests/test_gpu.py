"""The CUDA path: the same code on a GPU when torch sees one (skipped without). Without one,
asking for it is one line, not a traceback."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from endopipe.pipeline.errors import ConfigError
from endopipe.stages.nerf.render import pick_device
from tests.tube_scene import tiny_config, tiny_setup

CUDA = torch.cuda.is_available()


@pytest.mark.skipif(CUDA, reason="a CUDA device is present")
def test_asking_for_cuda_without_one_is_one_line() -> None:
    with pytest.raises(ConfigError, match="torch sees no CUDA device"):
        pick_device("cuda")
    assert pick_device("auto").type == "cpu"


@pytest.mark.skipif(not CUDA, reason="no CUDA device")
def test_the_nerf_trains_and_bakes_depth_on_the_gpu(tmp_path) -> None:
    from endopipe.stages.nerf.baked import BakedSurface, FarSettings
    from endopipe.stages.nerf.train import Trainer

    cfg = tiny_config(steps=60, device="cuda")
    frames, train, _, prior, box, k, poses, _ = tiny_setup(cfg, device="cuda")
    trainer = Trainer(cfg, frames, train, prior, box, tmp_path, lambda _: None)
    first = trainer.step()["loss"]
    trainer.fit()
    assert trainer.model.log_gain.device.type == "cuda"
    assert trainer.step()["loss"] < first
    baked = BakedSurface.bake(trainer.model.eval(), prior, poses, k, far=FarSettings())
    out = baked.render_depth(k, poses[0])
    assert np.isfinite(out["depth"]).all() and (out["depth"] > 0).mean() > 0.5
