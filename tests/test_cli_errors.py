"""Bad input: one clear line, a non-zero exit, no traceback, nothing in the case's stage folders."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from endopipe.cli import main
from tests.conftest import textured_frames, write_video


def run_cli(capsys: pytest.CaptureFixture, *args: str) -> tuple[int, str]:
    code = main(list(args))
    captured = capsys.readouterr()
    return code, captured.err + captured.out


def assert_clean_failure(code: int, output: str, workdir: Path, expect: str) -> None:
    assert code != 0
    assert "Traceback" not in output
    lines = [line for line in output.strip().splitlines() if line.strip()]
    assert lines and "error" in lines[-1].lower(), output
    assert expect.lower() in output.lower(), output
    stage_dirs = list(workdir.glob("*/[0-9][0-9]_*")) + list(workdir.glob("*/.[0-9][0-9]_*"))
    assert stage_dirs == [], stage_dirs


@pytest.fixture()
def video(tmp_path: Path) -> Path:
    return write_video(tmp_path / "good.mp4", textured_frames(12))


def test_missing_path(tmp_path: Path, capsys) -> None:
    code, out = run_cli(
        capsys, "run", str(tmp_path / "nope.mp4"), "--workdir", str(tmp_path / "wd")
    )
    assert_clean_failure(code, out, tmp_path / "wd", "input not found")


def test_empty_file(tmp_path: Path, capsys) -> None:
    (tmp_path / "empty.mp4").write_bytes(b"")
    code, out = run_cli(
        capsys, "run", str(tmp_path / "empty.mp4"), "--workdir", str(tmp_path / "wd")
    )
    assert_clean_failure(code, out, tmp_path / "wd", "is empty")


def test_text_file_named_mp4(tmp_path: Path, capsys) -> None:
    (tmp_path / "notes.mp4").write_text("these are not video frames\n" * 20)
    code, out = run_cli(
        capsys, "run", str(tmp_path / "notes.mp4"), "--workdir", str(tmp_path / "wd")
    )
    assert_clean_failure(code, out, tmp_path / "wd", "cannot read")


def test_truncated_mp4(tmp_path: Path, video: Path, capsys) -> None:
    data = video.read_bytes()
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(data[: len(data) * 2 // 3])
    code, out = run_cli(capsys, "run", str(cut), "--workdir", str(tmp_path / "wd"))
    assert_clean_failure(code, out, tmp_path / "wd", "cut.mp4")


def test_one_frame_video(tmp_path: Path, capsys) -> None:
    one = write_video(tmp_path / "one.mp4", textured_frames(1))
    code, out = run_cli(capsys, "run", str(one), "--workdir", str(tmp_path / "wd"))
    assert_clean_failure(code, out, tmp_path / "wd", "usable frame")


def test_all_black_video(tmp_path: Path, capsys) -> None:
    black = write_video(tmp_path / "black.mp4", [np.zeros((128, 160, 3), np.uint8)] * 10)
    code, out = run_cli(capsys, "run", str(black), "--workdir", str(tmp_path / "wd"))
    assert_clean_failure(code, out, tmp_path / "wd", "black")


def test_unknown_set_key(tmp_path: Path, video: Path, capsys) -> None:
    code, out = run_cli(
        capsys, "run", str(video), "--workdir", str(tmp_path / "wd"), "--set", "ingest.strid=2"
    )
    assert_clean_failure(code, out, tmp_path / "wd", "unknown key 'ingest.strid'")
    assert "stride" in out  # the valid choices are named


def test_wrong_type_for_key(tmp_path: Path, video: Path, capsys) -> None:
    code, out = run_cli(
        capsys, "run", str(video), "--workdir", str(tmp_path / "wd"), "--set", "ingest.stride=two"
    )
    assert_clean_failure(code, out, tmp_path / "wd", "ingest.stride")


def test_unwritable_workdir(tmp_path: Path, video: Path, capsys) -> None:
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    code, out = run_cli(capsys, "run", str(video), "--workdir", str(blocker / "wd"))
    assert_clean_failure(code, out, tmp_path, "cannot write to workdir")


def test_unknown_stage_for_until(tmp_path: Path, video: Path, capsys) -> None:
    code, out = run_cli(
        capsys, "run", str(video), "--workdir", str(tmp_path / "wd"), "--until", "x"
    )
    assert_clean_failure(code, out, tmp_path / "wd", "unknown stage 'x'")


@pytest.mark.parametrize(
    ("args", "expect"),
    [
        (["run", "a.mp4", "extra"], "unexpected extra argument"),
        (["run", "a.mp4", "--no-such-flag"], "no such option"),
        (["run"], "missing argument"),
    ],
)
def test_usage_errors_are_one_line_exit_2(tmp_path: Path, capsys, args, expect) -> None:
    """A mistyped command line is the user's error, not an endopipe bug: exit 2, no "internal"."""
    code, out = run_cli(capsys, *args)
    assert code == 2, out
    assert "internal error" not in out
    assert_clean_failure(code, out, tmp_path, expect)
