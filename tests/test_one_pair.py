"""One stereo pair is enough for depth: a SCARED keyframe as it ships (its two images, its
calibration, its structured-light depth) runs with no flags to the end, with no camera path and
no field, and its depth is the rig's, metric, scored against the truth. A calibration turned by
2 degrees (its rows tilted) or stated for half the image size is found and mended to the true
one's depth; the pair's rig is checked at the images' own size (480 px, the working size 320)."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from endopipe.cli import main
from endopipe.commands.synth import other_layout
from endopipe.stages.depth.view import DepthView
from endopipe.stages.ingest.view import IngestView
from endopipe.stages.io.datasets import detect_dataset, open_dataset
from endopipe.stages.nerf.view import NerfView
from endopipe.stages.poses.view import PosesView
from endopipe.synth import SynthConfig, generate_case
from endopipe.synth.scared_sink import spoil_calibration

BASELINE_MM = 5.0


@pytest.fixture(scope="module")
def keyframe(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A synthetic keyframe laid out as SCARED ships one without its video: Left_Image.png,
    Right_Image.png, the calibration and left_depth_map.tiff (the truth)."""
    out = tmp_path_factory.mktemp("scared") / "keyframe_1"
    cfg = SynthConfig(seed=3, frames=2, width=480, height=384, stereo_baseline_mm=BASELINE_MM)
    generate_case(out, cfg, layout=other_layout("scared", BASELINE_MM))
    shutil.rmtree(out / "data")
    shutil.rmtree(out / "gt")  # the truth is the keyframe's own depth map, as SCARED ships it
    return out


def variant(keyframe: Path, folder: Path, turn_deg: float = 0.0, half: bool = False) -> Path:
    """A copy of the keyframe whose calibration is turned by `turn_deg` about the rows' axis
    (and a quarter of that about the optical axis) or stated for half the image size."""
    out = folder / "keyframe_1"
    shutil.copytree(keyframe, out)
    spoil_calibration(out, (turn_deg, 0.0, 0.25 * turn_deg), half)
    return out


def run_case(folder: Path, workdir: Path, *args: str) -> Path:
    assert main(["run", str(folder), "--workdir", str(workdir), "--quiet", *args]) == 0
    return workdir / folder.name


@pytest.fixture(scope="module")
def truth_run(keyframe: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return run_case(keyframe, tmp_path_factory.mktemp("wd"))


def unscaled(case: Path) -> tuple[float, float]:
    m = DepthView(case / "05_depth").metrics
    assert m is not None and m.unscaled is not None and m.gt_kind == "exact"
    return m.unscaled.abs_rel, m.unscaled.coverage


def test_a_keyframe_alone_is_one_stereo_pair(keyframe: Path) -> None:
    assert detect_dataset(keyframe) == "scared"
    source = open_dataset(keyframe, "scared")
    assert [f.source_index for f in source.frames()] == [0]
    assert source.stereo is not None and source.stereo.baseline_mm == pytest.approx(BASELINE_MM)
    right = source.stereo.right(0)
    assert right is not None and right.shape == (384, 480, 3)
    assert source.stereo.right(1) is None


def test_it_runs_to_the_end_with_the_rigs_depth_and_no_path_nor_field(truth_run: Path) -> None:
    ingest = IngestView(truth_run / "01_ingest")
    assert ingest.one_pair and ingest.summary.one_pair is not None
    poses = PosesView(truth_run / "02_poses")
    assert poses.registered == [0] and poses.metric and poses.one_pair
    assert np.allclose(poses.c2w[0], np.eye(4))
    assert poses.summary.verdict == "not assessed"  # one pose: nothing to call right
    nerf = NerfView(truth_run / "04_nerf")
    assert not nerf.trained and not nerf.model_path.exists()
    depth = DepthView(truth_run / "05_depth")
    assert depth.summary.renderer == "stereo"
    assert np.array_equal(depth.depth(0), ingest.stereo_depth(0))
    assert (truth_run / "06_mesh" / "mesh.ply").is_file()
    page = (truth_run / "07_report" / "report.html").read_text()
    assert "Metric depth AbsRel" in page and "no field was trained" in page


def test_its_depth_is_metric_and_scored_against_the_keyframes_truth(truth_run: Path) -> None:
    abs_rel, coverage = unscaled(truth_run)
    # measured: 0.0183 unscaled on 72% of the truth's pixels (the radial guess: 0.17)
    assert abs_rel < 0.03, abs_rel
    assert coverage > 0.65, coverage


def test_a_turned_calibration_is_mended_to_the_true_ones_depth(
    keyframe: Path, truth_run: Path, tmp_path: Path
) -> None:
    case = run_case(variant(keyframe, tmp_path / "in", turn_deg=2.0), tmp_path / "wd")
    rig = IngestView(case / "01_ingest").file.stereo
    assert rig is not None and rig.rig is not None and rig.rig.right_rotation is not None
    assert rig.rig.vertical_px > 3 and rig.rig.vertical_mended_px < 0.5
    abs_rel, coverage = unscaled(case)
    true_abs_rel, true_coverage = unscaled(truth_run)
    # measured: 0.0191 against 0.0183 with the true calibration (1.98 of its 2.06 degrees
    # found); with a toe-in fitted to the matches' noise too (the 3-way matcher), 0.032
    assert abs_rel < 1.1 * true_abs_rel + 0.001, (abs_rel, true_abs_rel)
    assert coverage > 0.9 * true_coverage


def test_a_calibration_for_half_the_size_is_rescaled_aloud(
    keyframe: Path, truth_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    case = run_case(
        variant(keyframe, tmp_path / "in", half=True), tmp_path / "wd", "--until", "depth"
    )
    said = IngestView(case / "01_ingest").summary.calibration_check
    assert said is not None and "240x192 frames" in said and "rescaled" in said
    assert "rescaled" in capsys.readouterr().err
    assert unscaled(case)[0] == pytest.approx(unscaled(truth_run)[0], rel=0.02)


def test_a_pair_of_two_sizes_is_one_line(
    keyframe: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "keyframe_1"
    shutil.copytree(keyframe, bad)
    right = cv2.imread(str(bad / "Right_Image.png"))
    cv2.imwrite(str(bad / "Right_Image.png"), cv2.resize(right, (240, 192)))
    assert main(["run", str(bad), "--workdir", str(tmp_path / "wd"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "one size" in err[0] and "Traceback" not in err[0]
    assert not (tmp_path / "wd" / "keyframe_1" / "01_ingest").exists()


def test_two_frames_of_one_eye_are_still_too_few(tmp_path: Path, capsys) -> None:
    folder = tmp_path / "frames"
    folder.mkdir()
    rng = np.random.default_rng(0)
    for i in range(2):
        cv2.imwrite(str(folder / f"{i:04d}.png"), rng.integers(0, 255, (96, 128, 3), np.uint8))
    assert main(["run", str(folder), "--workdir", str(tmp_path / "wd"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "at least 3" in err and "Traceback" not in err
