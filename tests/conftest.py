"""Shared fixtures: small real inputs made on the fly (videos, synthetic cases)."""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
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


#: The tiny end-to-end case's settings: a short NeRF keeps the whole pipeline at about 2.5 minutes
#: on two CPU cores. One torch thread: the result then does not depend on the machine's load
#: (thread count changes the order of float reductions, and a 600-step NeRF is sensitive to it).
TINY = ["--set", "nerf.train.steps=600", "--set", "nerf.train.time_budget_s=null"]
TINY += ["--set", "mesh.eval_samples=50000", "--set", "nerf.train.threads=1"]
#: The tiny colon's red albedo sits at its ceiling, as C3VD's: a shorter albedo refit keeps it run.
TINY += ["--set", "nerf.train.colour_steps=200"]


@dataclass(frozen=True)
class TinyRun:
    case: Path  # the case's output folder (workdir/colon)
    wall_s: float  # how long the first, uncached run took


@pytest.fixture(scope="session")
def tiny_run(tmp_path_factory: pytest.TempPathFactory) -> TinyRun:
    """The real output of every stage: a tiny synthetic colon (16 frames, 160x128) run end to
    end through the CLI with TINY (about 2.5 minutes, once per session). Read it, never change
    it: tests that change it work on a copy."""
    from endopipe.cli import main
    from endopipe.synth import SynthConfig, generate_case

    src = tmp_path_factory.mktemp("tiny_input") / "colon"
    generate_case(src, SynthConfig(seed=3, frames=16, width=160, height=128))
    wd = tmp_path_factory.mktemp("tiny_wd")
    t0 = time.perf_counter()
    assert main(["run", str(src / "video.mp4"), "--workdir", str(wd), "--quiet", *TINY]) == 0
    return TinyRun(wd / "colon", time.perf_counter() - t0)


@pytest.fixture(scope="session")
def tiny_case(tiny_run: TinyRun) -> Path:
    return tiny_run.case


#: A synthetic colonoscope withdrawal (0.3 mm a frame) with a pause and spoiled frames, whose
#: truth lists every event (gt/synth.json): what keyframes by content and windows are tried on.
WITHDRAWAL = {
    "seed": 3,
    "frames": 120,
    "width": 320,
    "height": 256,
    "step_mm": 0.3,
    "pauses": 1,
    "pause_frames": 15,
    "blurred": 0.05,
    "washed_out": 0.05,
}


@pytest.fixture(scope="session")
def withdrawal(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The case folder of WITHDRAWAL (about 25 s to render, once per session)."""
    from endopipe.synth import SynthConfig, generate_case

    src = tmp_path_factory.mktemp("withdrawal") / "withdrawal"
    generate_case(src, SynthConfig(**WITHDRAWAL))
    return src


def pytest_configure(config: pytest.Config) -> None:
    """An xdist worker trains with one torch thread (and its subprocesses with one OpenMP
    thread): two workers on two cores would otherwise spin against each other."""
    if os.environ.get("PYTEST_XDIST_WORKER"):
        import torch

        os.environ["OMP_NUM_THREADS"] = "1"
        torch.set_num_threads(1)


#: Test files that use a costly session fixture, and that fixture: under `pytest -n` the files
#: sharing one run on one worker, so it is built once there.
SHARED_FIXTURE_OF_FILE = {
    "test_bench": "tiny_run",
    "test_pipeline_e2e": "tiny_run",
    "test_report": "tiny_run",
    "test_keyframes": "withdrawal",
    "test_recording": "withdrawal",
}


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config: pytest.Config, log):
    """xdist's `loadfile` (each file on one worker: its module fixtures are built once), with
    the files of SHARED_FIXTURE_OF_FILE grouped by their fixture. Another `--dist`: xdist's own."""
    if config.getvalue("dist") != "loadfile":
        return None
    from xdist.scheduler import LoadFileScheduling

    class SharedFixtureScheduling(LoadFileScheduling):
        def _split_scope(self, nodeid: str) -> str:
            file = super()._split_scope(nodeid)
            return SHARED_FIXTURE_OF_FILE.get(Path(file).stem, file)

    return SharedFixtureScheduling(config, log)
