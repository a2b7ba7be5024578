"""`endopipe run <workdir>/<case>`: the folder an earlier run made continues where it is, as if
its input were run again with that workdir and name; without its input, from its cache."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from endopipe.cli import main

#: Ground-truth poses (no COLMAP) and no NeRF: three real stages in a few seconds.
RUN = ["--until", "centerline", "--set", "poses.source=gt", "--quiet"]


@pytest.fixture(scope="module")
def workdir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """An 8-frame synthetic colon run through ingest, poses and centerline: <root>/wd/colon."""
    from endopipe.synth import SynthConfig, generate_case

    root = tmp_path_factory.mktemp("case_folder")
    generate_case(root / "colon", SynthConfig(seed=3, frames=8, width=96, height=80))
    assert (
        main(["run", str(root / "colon" / "video.mp4"), "--workdir", str(root / "wd"), *RUN]) == 0
    )
    return root / "wd"


def run(capsys: pytest.CaptureFixture, *args: str) -> tuple[int, str]:
    capsys.readouterr()
    code = main(["run", *args])
    captured = capsys.readouterr()
    return code, captured.err + captured.out


def test_running_the_case_folder_reuses_every_stage(
    workdir: Path, capsys: pytest.CaptureFixture
) -> None:
    case_json = (workdir / "colon" / "case.json").read_text()
    code, out = run(capsys, str(workdir / "colon"), *RUN)
    assert code == 0, out
    assert "colon: ran 0 stage(s), 3 cached" in out
    assert (workdir / "colon" / "case.json").read_text() == case_json
    assert sorted(p.name for p in workdir.iterdir()) == ["colon"]  # no case made beside it


def test_the_case_folder_continues_with_its_last_runs_settings(
    workdir: Path, capsys: pytest.CaptureFixture
) -> None:
    """Without the first run's --set poses.source=gt nothing re-runs: the case's config.yaml is
    the base, and a --set given now still layers on it."""
    code, out = run(capsys, str(workdir / "colon"), "--until", "centerline", "--quiet")
    assert code == 0, out
    assert "colon: ran 0 stage(s), 3 cached" in out
    code, out = run(
        capsys,
        str(workdir / "colon"),
        "--until",
        "centerline",
        "--dry-run",
        "--set",
        "centerline.prior=tube",
    )
    assert code == 0, out
    states = [line.split()[:2] for line in out.splitlines() if line.strip()]
    assert states == [["ingest", "cached"], ["poses", "cached"], ["centerline", "would"]]


def test_a_dry_run_of_the_case_folder_shows_every_stage_cached(
    workdir: Path, capsys: pytest.CaptureFixture
) -> None:
    code, out = run(capsys, str(workdir / "colon"), *RUN, "--dry-run")
    assert code == 0, out
    states = [line.split()[:2] for line in out.splitlines() if line.strip()]
    assert states == [["ingest", "cached"], ["poses", "cached"], ["centerline", "cached"]]


def test_the_case_folder_honours_from(
    workdir: Path, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    shutil.copytree(workdir, tmp_path / "wd")
    code, out = run(capsys, str(tmp_path / "wd" / "colon"), *RUN, "--from", "centerline")
    assert code == 0, out
    assert "colon: ran 1 stage(s), 2 cached" in out


def test_another_workdir_or_name_is_refused_not_ignored(
    workdir: Path, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    for extra in (["--name", "other"], ["--workdir", str(tmp_path)]):
        code, out = run(capsys, str(workdir / "colon"), *RUN, *extra)
        assert code == 2, out
        assert "does not apply" in out and extra[0] in out
    assert list(tmp_path.iterdir()) == []


def test_without_its_input_the_case_runs_from_its_cache_or_says_what_to_do(
    workdir: Path, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    case = tmp_path / "wd" / "colon"
    shutil.copytree(workdir / "colon", case)
    info = json.loads((case / "case.json").read_text())
    info.update(input=str(tmp_path / "gone" / "video.mp4"), gt_dir=str(tmp_path / "gone" / "gt"))
    (case / "case.json").write_text(json.dumps(info))

    code, out = run(capsys, str(case), *RUN)
    assert code == 0, out
    assert "colon: ran 0 stage(s), 3 cached" in out

    code, out = run(capsys, str(case), *RUN, "--from", "ingest")
    assert code == 2, out
    (line,) = [line for line in out.splitlines() if line.strip()]
    assert "are gone and ingest must re-run (--from ingest)" in line
    assert line.endswith(f"endopipe run NEW_PATH --workdir {case.parent} --name colon")


def test_a_bad_set_on_the_case_folder_blames_the_set_and_a_bad_saved_file_blames_it(
    workdir: Path, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """A wrong --set is named as the user's, not as the case's saved settings; saved settings
    that no longer load are named with what to do. Either way nothing runs."""
    case = tmp_path / "wd" / "colon"
    shutil.copytree(workdir / "colon", case)
    code, out = run(capsys, str(case), *RUN, "--set", "nerf.train.steps=-1")
    assert code == 2, out
    assert "nerf.train.steps" in out and "another version" not in out
    saved = case / "config.yaml"
    saved.write_text(saved.read_text().replace("  steps: ", "  steps: many # ", 1))
    code, out = run(capsys, str(case), *RUN)
    assert code == 2, out
    assert "another version" in out and str(saved) in out
