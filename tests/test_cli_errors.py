"""Bad input: one clear line, a non-zero exit, no traceback, nothing in the case's stage folders."""

from __future__ import annotations

import subprocess
import sys
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


@pytest.mark.parametrize(
    ("flags", "expect"),
    [
        (["--executor", "slrum"], "'--executor': 'slrum' is not one of local, slurm, ray"),
        (["--window", "20", "--overlap", "20"], "'--overlap'"),
    ],
)
def test_recording_options_refused_on_a_short_clip(
    tmp_path: Path, video: Path, capsys, flags: list[str], expect: str
) -> None:
    """A typo in where windows run is refused even when the input is too short to need them:
    otherwise the same command silently runs locally today and fails on a long input."""
    code, out = run_cli(capsys, "run", str(video), "--workdir", str(tmp_path / "wd"), *flags)
    assert code == 2, out
    assert_clean_failure(code, out, tmp_path / "wd", expect)


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


def _image_folder(folder: Path, sizes: list[tuple[int, int]]) -> Path:
    """PNG frames of the given (width, height), in order."""
    import cv2

    folder.mkdir()
    for i, (w, h) in enumerate(sizes):
        cv2.imwrite(str(folder / f"frame_{i:03d}.png"), textured_frames(1, w, h, seed=i)[0])
    return folder


def test_mixed_image_sizes_are_an_input_error(tmp_path: Path, capsys) -> None:
    """One camera, one resolution: refused in one line (exit 2) before a case folder exists."""
    images = _image_folder(tmp_path / "imgs", [(160, 128)] * 5 + [(240, 200)] * 2)
    wd = tmp_path / "wd"
    code, out = run_cli(capsys, "run", str(images), "--workdir", str(wd))
    assert code == 2, out
    assert "internal error" not in out
    assert_clean_failure(code, out, wd, "images differ in size")
    assert "frame_005.png is 240x200" in out and "160x128" in out
    assert not (wd / "imgs").exists(), "nothing is written for an input that cannot be used"


def test_too_few_frames_names_only_settings_that_dropped_frames(tmp_path: Path, capsys) -> None:
    """With stride 1, "lower the stride" is no advice; with stride 2 it is, with its value."""
    one = write_video(tmp_path / "one.mp4", textured_frames(1))
    code, out = run_cli(capsys, "run", str(one), "--workdir", str(tmp_path / "wd"))
    assert_clean_failure(code, out, tmp_path / "wd", "usable frame")
    assert "stride" not in out and "longer video" in out
    four = write_video(tmp_path / "four.mp4", textured_frames(4))
    args = ["run", str(four), "--workdir", str(tmp_path / "wd2"), "--set", "ingest.stride=2"]
    code, out = run_cli(capsys, *args, "--set", "ingest.drop_duplicates=false")
    assert_clean_failure(code, out, tmp_path / "wd2", "usable frame")
    assert "lower --set ingest.stride (now 2)" in out


def test_invalid_intrinsics_name_the_field(tmp_path: Path, video: Path, capsys) -> None:
    k = tmp_path / "k.json"
    k.write_text('{"width": 160, "height": 128, "fx": -500, "fy": 500, "cx": 80, "cy": 64}')
    args = ["run", str(video), "--intrinsics", str(k), "--workdir", str(tmp_path / "wd")]
    code, out = run_cli(capsys, *args)
    assert_clean_failure(code, out, tmp_path / "wd", "fx: must be > 0, got -500")
    assert "validation error" not in out


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "endopipe", *args]


def test_locked_case_names_it_and_wait_says_it_waits(tmp_path: Path) -> None:
    """A case named like a common word reads right; --wait says what it waits for."""
    from filelock import FileLock

    video = write_video(tmp_path / "case.mp4", textured_frames(12))
    wd = tmp_path / "wd"
    run_args = _cli("run", str(video), "--workdir", str(wd), "--until", "ingest", "--quiet")
    assert subprocess.run([*run_args, "--dry-run"], capture_output=True).returncode == 0
    with FileLock(str(wd / "case" / ".lock")):  # another run holds the case
        busy = subprocess.run(run_args, capture_output=True, text=True, timeout=120)
        assert busy.returncode == 4, busy.stderr
        assert "another endopipe run is processing case 'case'" in busy.stderr
        assert "case case" not in busy.stderr
        waiting = subprocess.Popen([*run_args, "--wait"], stderr=subprocess.PIPE, text=True)
        first_line = waiting.stderr.readline()
        assert "waiting for the other endopipe run on case 'case'" in first_line
    _, rest = waiting.communicate(timeout=120)
    assert waiting.returncode == 0, rest


def test_an_error_message_keeps_its_square_brackets(tmp_path: Path, capsys) -> None:
    """Messages are printed as text, not rich markup: `a[b]c` in one must reach the user
    whole (as markup, `[b]` is a bold tag and vanishes)."""
    code = main(["run", str(tmp_path), "--set", "nerf.train.steps=a[b]c"])
    err = capsys.readouterr()
    assert code == 2
    assert "nerf.train.steps" in err.err and "(got 'a[b]c')" in err.err, err


@pytest.mark.parametrize("found", ["4.1.0", "3.11.1", "5.0.0"])
def test_a_pycolmap_outside_the_declared_range_is_refused_at_start_up(
    tmp_path: Path, video: Path, capsys, monkeypatch: pytest.MonkeyPatch, found: str
) -> None:
    """pycolmap 4.0 and 4.1 lack the global mapper's options the poses stage sets: a run would
    fail minutes in, inside COLMAP; it is refused before any work, naming what to install."""
    import importlib.metadata

    real = importlib.metadata.version
    monkeypatch.setattr(
        importlib.metadata, "version", lambda name: found if name == "pycolmap" else real(name)
    )
    code, out = run_cli(capsys, "run", str(video), "--workdir", str(tmp_path / "wd"))
    assert code == 2
    assert_clean_failure(code, out, tmp_path / "wd", f"pycolmap {found} is installed")
    assert "pip install 'pycolmap" in out and not (tmp_path / "wd").exists()
