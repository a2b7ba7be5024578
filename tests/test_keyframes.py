"""Keyframes by content on a synthetic withdrawal whose truth lists every pause and every spoiled
frame: ingest must drop each spoiled frame for its reason, keep none of the frames where the
camera stood still, and space the kept frames about as the bench's frames are spaced (1 mm)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from endopipe.cli import main
from tests.conftest import WITHDRAWAL


@pytest.fixture(scope="module")
def recording(
    withdrawal: Path, tmp_path_factory: pytest.TempPathFactory
) -> tuple[Path, dict, dict]:
    wd = tmp_path_factory.mktemp("wd")
    args = ["run", str(withdrawal), "--workdir", str(wd), "--until", "ingest", "--quiet"]
    assert main([*args, "--set", "ingest.keyframes.mode=content"]) == 0
    frames = json.loads((wd / "withdrawal" / "01_ingest" / "frames.json").read_text())
    events = json.loads((withdrawal / "gt" / "synth.json").read_text())["events"]
    return withdrawal, frames, events


def test_synth_recording_lists_its_events(recording: tuple[Path, dict, dict]) -> None:
    src, _, events = recording
    poses = np.array(json.loads((src / "gt" / "poses.json").read_text())["poses"])
    assert len(events["paused"]) == WITHDRAWAL["pause_frames"]
    assert len(events["blurred"]) == len(events["washed_out"]) == 6  # 5% of 120
    for i in events["paused"]:  # the camera stands where it stood the frame before
        assert np.allclose(poses[i], poses[i - 1])
    moving = np.setdiff1d(np.arange(1, len(poses)), events["paused"])
    steps = np.linalg.norm(poses[moving, :3, 3] - poses[moving - 1, :3, 3], axis=1)
    assert 0.2 < np.median(steps) < 0.4  # step_mm 0.3 +- 25 %


def test_every_spoiled_frame_is_dropped_for_its_reason(recording: tuple[Path, dict, dict]) -> None:
    _, frames, events = recording
    dropped = {reason: set(found) for reason, found in frames["dropped_frames"].items()}
    for kind in ("blurred", "washed_out"):
        assert dropped.get(kind, set()) == set(events[kind]), kind
    assert frames["dropped"]["blurred"] == len(events["blurred"])


def test_no_frame_of_a_pause_is_kept(recording: tuple[Path, dict, dict]) -> None:
    _, frames, events = recording
    kept = {f["source_index"] for f in frames["frames"]}
    assert not kept & set(events["paused"])
    still = set(frames["dropped_frames"].get("still", []))
    assert len(still & set(events["paused"])) >= 0.9 * len(events["paused"])
    assert len(still - set(events["paused"])) <= 2  # a moving camera is rarely called still


def test_keyframes_are_spaced_like_the_bench_frames(recording: tuple[Path, dict, dict]) -> None:
    src, frames, _ = recording
    poses = np.array(json.loads((src / "gt" / "poses.json").read_text())["poses"])
    kept = [f["source_index"] for f in frames["frames"]]
    spacing = np.linalg.norm(np.diff(poses[kept, :3, 3], axis=0), axis=1)
    print(f"{len(kept)} keyframes of 120, spacing median {np.median(spacing):.2f} mm")
    assert 0.6 < np.median(spacing) < 1.4 and spacing.max() < 3.0
    assert sum(frames["dropped"].values()) + len(kept) == WITHDRAWAL["frames"]
