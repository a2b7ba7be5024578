"""A StereoMIS sequence read as it ships: found by its files, rectified with its calibration, the
right eye as stereo pairs, the kinematics (groundtruth.txt, metres) as known poses."""

from __future__ import annotations

import configparser
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from endopipe.cli import main
from endopipe.pipeline.errors import InputError
from endopipe.stages.ingest.view import IngestView
from endopipe.stages.io.cases import detect_format, find_cases
from endopipe.stages.io.datasets import detect_dataset, open_dataset
from endopipe.stages.io.ground_truth import open_case_truth
from endopipe.stages.io.stereomis import CALIBRATION, ground_truth
from endopipe.synth import SynthConfig
from endopipe.synth.generate import intrinsics_for
from endopipe.synth.stereomis_sink import VIDEO

BASELINE_MM = 5.0
WIDTH, HEIGHT, FRAMES = 128, 96, 4


@pytest.fixture(scope="module")
def seq(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """StereoMIS_0_0_1/P1 as `endopipe synth --layout stereomis --stereo` writes it."""
    root = tmp_path_factory.mktemp("data") / "StereoMIS_0_0_1"
    args = ["--frames", str(FRAMES), "--width", str(WIDTH), "--height", str(HEIGHT), "--seed", "5"]
    assert main(["synth", str(root / "P1"), "--layout", "stereomis", "--stereo", *args]) == 0
    (root / "sequences.txt").write_text("sequence,stride\nP1,1\n")
    return root / "P1"


def config_of(seq: Path) -> SynthConfig:
    return SynthConfig.model_validate(json.loads((seq / "gt" / "synth.json").read_text())["config"])


def copy_of(seq: Path, folder: Path) -> Path:
    """The sequence's files in `folder` (video and poses linked, the calibration copied)."""
    out = folder / "P1"
    out.mkdir(parents=True)
    for name in (VIDEO, "groundtruth.txt", "masks", "gt"):
        (out / name).symlink_to(seq / name)
    shutil.copy(seq / CALIBRATION, out / CALIBRATION)
    return out


def rewrite(ini_file: Path, **eyes: dict[str, float]) -> None:
    """Set keys of the ini's sections: rewrite(f, StereoLeft={"res_x": 64}, ...)."""
    ini = configparser.ConfigParser()
    ini.read(ini_file)
    for section, values in eyes.items():
        for key, value in values.items():
            ini[section][key] = repr(value)
    with ini_file.open("w") as f:
        ini.write(f)


def test_sequence_reads_with_its_calibration(seq: Path) -> None:
    assert detect_dataset(seq) == "stereomis"
    source = open_dataset(seq, "stereomis")
    k, truth = source.intrinsics, intrinsics_for(config_of(seq))
    assert k is not None and (k.width, k.height) == (WIDTH, HEIGHT) and not k.distorted
    # an identical, already rectified pair: stereoRectify keeps the camera
    assert abs(k.fx - truth.fx) < 1e-6 and abs(k.fy - truth.fy) < 1e-6
    assert abs(k.cx - truth.cx) < 1e-6 and abs(k.cy - truth.cy) < 1e-6
    assert source.calibration_said is None
    frames = list(source.frames())
    assert len(frames) == FRAMES and frames[0].rgb.shape == (HEIGHT, WIDTH, 3)


def test_right_eye_is_the_stereo_pair(seq: Path) -> None:
    source = open_dataset(seq, "stereomis")
    assert source.stereo is not None
    assert source.stereo.baseline_mm == pytest.approx(BASELINE_MM)
    assert source.stereo.source == str(seq / CALIBRATION)
    left = [f.rgb for f in source.frames()]
    right = [source.stereo.right(i) for i in (0, 1, 3)]
    assert all(r is not None and r.shape == (HEIGHT, WIDTH, 3) for r in right)
    assert source.stereo.right(0) is not None  # asked again from the start
    assert source.stereo.right(FRAMES + 5) is None
    # the right eye is another view, not the left one again
    assert np.abs(right[0].astype(int) - left[0].astype(int)).mean() > 2


def test_kinematics_are_known_poses(seq: Path) -> None:
    source = open_dataset(seq, "stereomis")
    truth = open_case_truth(seq / "gt").poses()
    assert source.known_poses is not None and len(source.known_poses) == FRAMES
    assert np.abs(np.array(source.known_poses) - np.array(truth)).max() < 1e-6
    assert "groundtruth.txt" in (source.known_poses_from or "")
    # the synthetic sequence's exact gt/ is its truth; StereoMIS itself ships none
    assert source.ground_truth() is not None


def test_detection_takes_its_files_only(seq: Path, tmp_path: Path) -> None:
    root = seq.parent
    assert detect_format(root) is None  # the release's root: sequences.txt, not a sequence
    assert [(c.path, c.format) for c in find_cases(root)] == [(seq, "stereomis")]
    two = copy_of(seq, tmp_path / "two")
    (two / "other.mp4").symlink_to(seq / VIDEO)
    assert detect_dataset(two) is None  # one video a sequence, not two
    bare = tmp_path / "bare"
    bare.mkdir()
    (bare / VIDEO).symlink_to(seq / VIDEO)
    assert detect_dataset(bare) is None  # a video alone is no StereoMIS sequence
    assert ground_truth(bare) is None


def test_a_calibration_for_half_the_size_is_rescaled_with_a_line(seq: Path, tmp_path: Path) -> None:
    half = copy_of(seq, tmp_path / "half")
    truth = intrinsics_for(config_of(seq))
    stated = truth.zoomed(0.5, 0.5, WIDTH // 2, HEIGHT // 2)  # pixel-centre convention
    eye = {"res_x": WIDTH // 2, "res_y": HEIGHT // 2, "fc_x": stated.fx, "fc_y": stated.fy}
    eye |= {"cc_x": stated.cx, "cc_y": stated.cy}
    rewrite(half / CALIBRATION, StereoLeft=eye, StereoRight=eye)
    source = open_dataset(half, "stereomis")
    k = source.intrinsics
    assert k is not None and (k.width, k.height) == (WIDTH, HEIGHT)
    assert abs(k.fx - truth.fx) < 1e-6 and abs(k.cx - truth.cx) < 1e-6
    assert abs(k.cy - truth.cy) < 1e-6
    said = source.calibration_said
    assert said is not None and "\n" not in said
    assert f"{WIDTH // 2}x{HEIGHT // 2}" in said and f"{WIDTH}x{HEIGHT}" in said
    assert source.stereo is not None and source.stereo.baseline_mm == pytest.approx(BASELINE_MM)
    # another aspect ratio is not a smaller copy of these images: one line
    rewrite(half / CALIBRATION, StereoLeft={"res_y": HEIGHT // 3})
    with pytest.raises(InputError, match="another aspect ratio") as e:
        open_dataset(half, "stereomis")
    assert "\n" not in str(e.value)


@pytest.mark.parametrize(
    ("text", "said"),
    [
        ("res_x = 1280\n", "cannot read .* as an ini file"),
        ("[StereoLeft]\nres_x = 128\n", "has no \\[StereoRight\\] section"),
        (
            "[StereoLeft]\nres_x = 128\n[StereoRight]\nres_x = 128\n",
            "has no fc_x in \\[StereoLeft\\]",
        ),
    ],
)
def test_a_malformed_calibration_is_one_line(
    seq: Path, tmp_path: Path, text: str, said: str
) -> None:
    bad = copy_of(seq, tmp_path / "bad")
    (bad / CALIBRATION).write_text(text)
    with pytest.raises(InputError, match=said) as e:
        open_dataset(bad, "stereomis")
    assert "\n" not in str(e.value)


def test_it_runs_through_ingest_with_the_rigs_depth(seq: Path, tmp_path: Path) -> None:
    args = ["run", str(seq), "--workdir", str(tmp_path), "--until", "ingest", "--quiet"]
    assert main([*args, "--set", "ingest.drop_duplicates=false"]) == 0
    summary = IngestView(tmp_path / seq.name / "01_ingest").summary
    assert summary.stereo_baseline_mm == pytest.approx(BASELINE_MM)
    assert summary.stereo_coverage is not None and len(summary.stereo_coverage) == summary.kept
    assert summary.stereo_mean_coverage is not None and summary.stereo_mean_coverage > 0.5
    assert summary.known_poses is not None and "groundtruth.txt" in summary.known_poses
    # the rig's depth is metric: the synthetic truth's millimetres
    view = IngestView(tmp_path / seq.name / "01_ingest")
    truth = open_case_truth(seq / "gt")
    i = view.indices[0]
    depth, exact = view.stereo_depth(i), truth.depth(view.frame(i).source_index)
    assert depth is not None and exact is not None and depth.shape == exact.shape
    both = (depth > 0) & (exact > 0)
    assert np.median(np.abs(depth[both] - exact[both]) / exact[both]) < 0.05


def test_its_masks_mark_the_tissue_and_leave_the_tool_out(seq: Path, tmp_path: Path) -> None:
    """StereoMIS draws what to keep (nonzero): a zero patch is a tool, the rest tissue."""
    import cv2

    from endopipe.stages.ingest.config import ToolsConfig
    from endopipe.stages.ingest.tool_frames import FrameTools

    folder = tmp_path / "P1"
    folder.mkdir()
    for name in (VIDEO, "groundtruth.txt", "gt", CALIBRATION):
        (folder / name).symlink_to(seq / name)
    (folder / "masks").mkdir()
    mask = np.full((HEIGHT, WIDTH), 255, np.uint8)
    mask[:, : WIDTH // 4] = 0  # the tool, at the left edge
    cv2.imwrite(str(folder / "masks" / "000001l.png"), mask)
    source = open_dataset(folder, "stereomis")
    assert source.tool_masks is not None and source.tool_masks.polarity == "black_is_tool"
    tools = FrameTools(source.tool_masks, ToolsConfig())
    rgb = np.zeros((HEIGHT, WIDTH, 3), np.uint8)
    fov = np.full((HEIGHT, WIDTH), 255, np.uint8)
    tool = tools.of(1, rgb, fov, (WIDTH, HEIGHT))
    assert tool is not None and tool[:, : WIDTH // 4].all() and not tool[:, WIDTH // 4 :].any()
    assert not tools.of(0, rgb, fov, (WIDTH, HEIGHT)).any()  # no file: no tool
