"""Shared fixtures: small real inputs made on the fly (videos, synthetic cases)."""

from __future__ import annotations

from pathlib import Path

import av
import numpy as np
import pytest

import endopipe.stages  # noqa: F401  (cv2 before pycolmap, as in every entry point)

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def write_video(path: Path, frames: list[np.ndarray], fps: int = 10) -> Path:
    """Encode RGB uint8 frames as H.264 with PyAV (a real video file, no mocks)."""
    h, w = frames[0].shape[:2]
    with av.open(str(path), "w") as container:
        stream = container.add_stream("libx264", rate=fps)
        stream.width, stream.height, stream.pix_fmt = w, h, "yuv420p"
        stream.options = {"crf": "18"}
        for rgb in frames:
            for packet in stream.encode(av.VideoFrame.from_ndarray(rgb, format="rgb24")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    return path


def textured_frames(n: int, w: int = 160, h: int = 128, seed: int = 0) -> list[np.ndarray]:
    """A smooth random texture panning sideways: distinct, sharp, non-black frames."""
    rng = np.random.default_rng(seed)
    import cv2

    base = rng.random((h // 4, (w + 4 * n) // 4, 3)).astype(np.float32)
    base = cv2.resize(base, (w + 4 * n, h), interpolation=cv2.INTER_CUBIC)
    base = (np.clip(base, 0, 1) * 200 + 30).astype(np.uint8)
    return [np.ascontiguousarray(base[:, 4 * i : 4 * i + w]) for i in range(n)]


@pytest.fixture(scope="session")
def shared_data() -> Path:
    if not SHARED_DATA.is_dir():
        pytest.skip(f"shared data not found at {SHARED_DATA}")
    return SHARED_DATA


@pytest.fixture(scope="session")
def tiny_case(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The real output of every stage: a tiny synthetic colon (16 frames, 160x128) run end to
    end through the CLI with test_pipeline_e2e's TINY settings (about 2.5 minutes, once per
    session). Tests that change it work on a copy."""
    from endopipe.cli import main
    from endopipe.commands.synth import SynthConfig, generate_case
    from tests.test_pipeline_e2e import TINY

    src = tmp_path_factory.mktemp("tiny_input") / "colon"
    generate_case(src, SynthConfig(seed=3, frames=16, width=160, height=128))
    wd = tmp_path_factory.mktemp("tiny_wd")
    assert main(["run", str(src / "video.mp4"), "--workdir", str(wd), "--quiet", *TINY]) == 0
    return wd / "colon"
