"""`endopipe status` on a real small case (ingest and poses): it agrees with the run, names the
key that changed, and shows the stage running now."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from endopipe import cli
from endopipe.cli import main

RUN = ["--until", "poses", "--config", "demo", "--set", "ingest.max_frames=10", "--quiet"]


def endopipe(*args: str) -> list[str]:
    """The command line a user types, run in a real process."""
    return [sys.executable, "-m", "endopipe", *args]


@pytest.fixture(scope="module")
def workdir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 12-frame synthetic colon run through ingest and poses with a preset and a --set."""
    from endopipe.synth import SynthConfig, generate_case

    root = tmp_path_factory.mktemp("status")
    generate_case(root / "colon", SynthConfig(seed=3, frames=12, width=160, height=128))
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    cmd = endopipe("run", str(root / "colon" / "video.mp4"), "--workdir", str(root / "wd"), *RUN)
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=120, env=env)
    assert done.returncode == 0, done.stderr
    return root


def status(capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch, *args: str) -> dict:
    """`endopipe status ARGS` as printed: {stage: (state, why)}, plus the lines after the table."""
    monkeypatch.setattr(cli.out, "width", 200)  # one table row per line, as in a wide terminal
    capsys.readouterr()
    assert main(["status", *args]) == 0
    rows = {}
    for line in capsys.readouterr().out.splitlines():
        cells = [c.strip() for c in line.split("│")[1:-1]]
        if len(cells) == 4 and cells[0] != "stage":
            rows[cells[0]] = (cells[1], cells[2])
    return rows


def test_status_after_a_run_with_a_preset_and_set_is_fresh(
    workdir: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    rows = status(capsys, monkeypatch, "colon", "--workdir", str(workdir / "wd"))
    assert rows["ingest"] == ("fresh", "fresh") and rows["poses"] == ("fresh", "fresh")
    assert rows["nerf"][0] == "missing"  # never run (--until poses), not "stale"


def test_status_with_another_set_names_the_key(
    workdir: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    wd = str(workdir / "wd")
    same = status(capsys, monkeypatch, "colon", "--workdir", wd, "--set", "ingest.max_frames=10")
    assert same["ingest"][0] == same["poses"][0] == "fresh"  # the preset only touches nerf
    rows = status(capsys, monkeypatch, "colon", "--workdir", wd, "--set", "ingest.max_frames=8")
    assert rows["ingest"] == ("stale", "ingest.max_frames 10 -> 8")
    assert rows["poses"] == ("stale", "upstream ingest changed")


def test_status_follows_the_last_run_config(
    workdir: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    wd = workdir / "wd_changed"
    shutil.copytree(workdir / "wd", wd)
    run = ["run", str(workdir / "colon" / "video.mp4"), "--workdir", str(wd), "--quiet"]
    assert main([*run, "--until", "ingest", "--set", "ingest.max_frames=8"]) == 0
    rows = status(capsys, monkeypatch, "colon", "--workdir", str(wd))
    assert rows["ingest"] == ("fresh", "fresh")
    assert rows["poses"] == ("stale", "upstream ingest changed")
    back = status(capsys, monkeypatch, "colon", "--workdir", str(wd), *RUN[2:-1])
    assert back["ingest"] == ("stale", "ingest.max_frames 8 -> 10")


def test_status_shows_the_stage_running_now(
    workdir: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    wd = workdir / "wd_running"
    shutil.copytree(workdir / "wd", wd)
    cmd = endopipe("run", str(workdir / "colon" / "video.mp4"), "--workdir", str(wd), *RUN)
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    proc = subprocess.Popen([*cmd, "--force"], env=env, stderr=subprocess.PIPE, text=True)
    seen: dict[str, tuple[str, str]] = {}
    deadline = time.time() + 60
    while proc.poll() is None and time.time() < deadline and not seen:
        rows = status(capsys, monkeypatch, "colon", "--workdir", str(wd))
        seen = {stage: row for stage, row in rows.items() if row[0] == "running"}
        time.sleep(0.05)
    assert proc.wait(timeout=120) == 0, proc.stderr.read() if proc.stderr else ""
    assert set(seen) in ({"ingest"}, {"poses"}), seen
    (row,) = seen.values()
    assert f"pid {proc.pid}" in row[1]
    after = status(capsys, monkeypatch, "colon", "--workdir", str(wd))
    assert after["poses"] == ("fresh", "fresh")  # finished: nothing running any more
