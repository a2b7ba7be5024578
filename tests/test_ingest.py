"""The ingest stage on a synthetic colon with ground truth: masks, intrinsics, frame records."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from endopipe.cli import main


@pytest.fixture(scope="module")
def ingested(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    from endopipe.synth import SynthConfig, generate_case

    src = tmp_path_factory.mktemp("src") / "colon"
    generate_case(src, SynthConfig(seed=1, frames=6, width=320, height=256))
    wd = tmp_path_factory.mktemp("wd")
    args = ["run", str(src), "--workdir", str(wd), "--until", "ingest", "--quiet"]
    assert main([*args, "--set", "ingest.drop_duplicates=false"]) == 0
    return src, wd / "colon" / "01_ingest"


def test_specular_mask_matches_ground_truth(ingested: tuple[Path, Path]) -> None:
    src, out = ingested
    frames = json.loads((out / "frames.json").read_text())
    inter = union = 0
    for f in frames["frames"]:
        usable = cv2.imread(str(out / f["mask"]), cv2.IMREAD_GRAYSCALE)
        found = usable == 0  # full field of view here: every masked pixel is a specular
        gt = cv2.imread(str(src / "gt" / "specular" / f"{f['source_index']:06d}.png"), 0) > 0
        inter += int((found & gt).sum())
        union += int((found | gt).sum())
    iou = inter / union
    print(f"specular IoU against synthetic ground truth: {iou:.3f}")
    assert iou >= 0.6


def test_full_frame_fov_and_intrinsics(ingested: tuple[Path, Path]) -> None:
    src, out = ingested
    frames = json.loads((out / "frames.json").read_text())
    assert frames["fov_shape"] == "full"
    fov = cv2.imread(str(out / "fov_mask.png"), cv2.IMREAD_GRAYSCALE)
    assert (fov > 0).mean() > 0.99
    truth = json.loads((src / "intrinsics.json").read_text())
    assert frames["intrinsics"]["fx"] == pytest.approx(truth["fx"])
    assert [f["source_index"] for f in frames["frames"]] == list(range(6))
    assert (out / "contact_sheet.png").is_file()


def test_downscaling_scales_intrinsics(ingested: tuple[Path, Path], tmp_path: Path) -> None:
    src, _ = ingested
    args = ["run", str(src), "--workdir", str(tmp_path), "--until", "ingest", "--quiet"]
    assert (
        main([*args, "--set", "ingest.max_size=160", "--set", "ingest.drop_duplicates=false"]) == 0
    )
    frames = json.loads((tmp_path / "colon" / "01_ingest" / "frames.json").read_text())
    truth = json.loads((src / "intrinsics.json").read_text())
    assert (frames["width"], frames["height"]) == (160, 128)
    assert frames["intrinsics"]["fx"] == pytest.approx(truth["fx"] / 2)
    assert frames["intrinsics"]["cx"] == pytest.approx((truth["cx"] + 0.5) / 2 - 0.5)
    img = cv2.imread(str(tmp_path / "colon" / "01_ingest" / "frames" / "000000.png"))
    assert img.shape == (128, 160, 3) and np.std(img) > 5


def test_view_reads_what_ingest_wrote(ingested: tuple[Path, Path]) -> None:
    """Downstream code reads 01_ingest only through IngestView: the file contract's keys, each
    frame's image / mask / field of view at the working size, and its ground truth by frame."""
    from endopipe.stages.ingest.view import IngestView
    from endopipe.stages.io.ground_truth import depth_of_frame

    src, out = ingested
    raw = json.loads((out / "frames.json").read_text())
    assert list(raw) == [
        "frames", "intrinsics", "width", "height", "source", "gt_dir", "fov_shape", "dropped",
        "dropped_frames", "tools", "known_poses", "stereo", "depth_prior", "one_pair",
    ]  # fmt: skip
    assert list(raw["frames"][0]) == [
        "index", "source_index", "time_s", "file", "mask", "tool", "tool_share", "stereo",
        "stereo_share", "depth_prior",
    ]  # fmt: skip
    view = IngestView(out)
    assert view.indices == list(range(6)) and view.frame(4).source_index == 4
    assert not view.has_frame(6)
    img = view.image(3)
    on_disk = cv2.cvtColor(cv2.imread(str(out / "frames" / "000003.png")), cv2.COLOR_BGR2RGB)
    np.testing.assert_array_equal(img, on_disk)
    assert img.shape == (view.height, view.width, 3) == (256, 320, 3)
    assert view.mask(3).shape == img.shape[:2] and set(np.unique(view.mask(3))) <= {0, 255}
    assert (view.mask(3) == 0).any(), "the synthetic colon has specular highlights"
    assert view.fov().shape == img.shape[:2]
    truth = json.loads((src / "intrinsics.json").read_text())
    assert view.intrinsics is not None and view.intrinsics.fx == pytest.approx(truth["fx"])
    gt = view.ground_truth()
    assert gt is not None
    np.testing.assert_array_equal(
        depth_of_frame(gt, view.frame(2)), np.load(src / "gt" / "depth" / "000002.npy")
    )
    assert view.index_by_stem()["000005"] == 5
    assert view.index_by_source_index() == {i: i for i in range(6)}


def test_view_maps_an_image_folders_own_names(tmp_path: Path) -> None:
    """Pose files name frames by the input's files: the view maps those names to frames."""
    from endopipe.stages.ingest.view import IngestView

    rng = np.random.default_rng(0)
    folder = tmp_path / "scope"
    folder.mkdir()
    for n in range(5):
        img = cv2.resize(rng.integers(0, 255, (12, 16, 3), dtype=np.uint8), (64, 48))
        cv2.imwrite(str(folder / f"shot_{10 + 3 * n:04d}.png"), img)
    args = ["run", str(folder), "--workdir", str(tmp_path / "wd"), "--until", "ingest"]
    assert main([*args, "--quiet", "--set", "ingest.drop_blurred=false"]) == 0
    view = IngestView(tmp_path / "wd" / "scope" / "01_ingest")
    assert view.gt_dir is None and view.ground_truth() is None
    assert view.source_file_names() == [f"shot_{10 + 3 * n:04d}.png" for n in range(5)]
    assert view.index_by_source_stem() == {f"shot_{10 + 3 * n:04d}": n for n in range(5)}


# ----------------------------------------------- max_frames stops decoding


def ingest_summary(workdir: Path, name: str) -> dict:
    return json.loads((workdir / name / "01_ingest" / "manifest.json").read_text())["summary"]


def test_max_frames_stops_decoding_and_counts_what_was_not_read(tmp_path: Path, capsys) -> None:
    from tests.conftest import textured_frames, write_video

    video = write_video(tmp_path / "long.mp4", textured_frames(120, 64, 48))
    wd = tmp_path / "wd"
    args = ["run", str(video), "--workdir", str(wd), "--until", "ingest"]
    assert main([*args, "--set", "ingest.max_frames=20"]) == 0
    assert "kept 20 of 120 frames (100 not read)" in capsys.readouterr().err
    s = ingest_summary(wd, "long")
    counts = (s["source_frames"], s["read"], s["kept"], s["dropped"]["not_read"])
    assert counts == (120, 20, 20, 100)
    assert (
        main([*args, "--quiet", "--set", "ingest.max_frames=20", "--set", "ingest.stride=2"]) == 0
    )
    s = ingest_summary(wd, "long")
    counts = (s["read"], s["kept"], s["dropped"]["stride"], s["dropped"]["not_read"])
    assert counts == (39, 20, 19, 81)
    frames = json.loads((wd / "long" / "01_ingest" / "frames.json").read_text())["frames"]
    assert [f["source_index"] for f in frames] == list(range(0, 40, 2))


# ------------------------------- ground truth that does not match the input


@pytest.fixture(scope="module")
def small_case(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A synthetic case folder (8 frames, 96x80, full ground truth); tests change copies."""
    from endopipe.synth import SynthConfig, generate_case

    src = tmp_path_factory.mktemp("small") / "colon"
    generate_case(src, SynthConfig(seed=3, frames=8, width=96, height=80))
    return src


def copy_case(src: Path, tmp_path: Path) -> Path:
    import shutil

    return Path(shutil.copytree(src, tmp_path / "colon"))


def test_ground_truth_that_does_not_match_is_warned_and_recorded(
    small_case: Path, tmp_path: Path, capsys
) -> None:
    case = copy_case(small_case, tmp_path)
    for n in (6, 7):
        (case / "gt" / "depth" / f"{n:06d}.npy").unlink()
    poses = json.loads((case / "gt" / "poses.json").read_text())
    poses["poses"] = poses["poses"][:7]
    (case / "gt" / "poses.json").write_text(json.dumps(poses))
    wd = tmp_path / "wd"
    args = ["run", str(case), "--workdir", str(wd), "--until", "ingest", "--quiet"]
    assert main([*args, "--set", "ingest.drop_duplicates=false"]) == 0
    warnings = [line for line in capsys.readouterr().err.splitlines() if "warning" in line]
    assert warnings == [
        "warning: ground truth does not match the input: 6 depth map(s) for 8 frame(s); 2 of "
        "the 8 kept frame(s) have none (from input frame 6) and are not evaluated",
        "warning: ground truth does not match the input: 7 pose(s) for 8 frame(s); 1 of the 8 "
        "kept frame(s) have none (from input frame 7) and are not evaluated",
    ]
    s = ingest_summary(wd, "colon")
    assert (s["gt_frames_without_depth"], s["gt_frames_without_pose"]) == (2, 1)
    assert s["warnings"] == [w.removeprefix("warning: ") for w in warnings]
    from endopipe.stages.report.render import build_report

    page = build_report(wd / "colon", {"ingest": wd / "colon" / "01_ingest"})
    assert page.count("<th>Warning</th>") == 2 and "6 depth map(s) for 8 frame(s)" in page


def test_ground_truth_for_more_frames_than_the_input_is_questioned(
    small_case: Path, tmp_path: Path
) -> None:
    from endopipe.stages.io.ground_truth import GroundTruth, coverage

    gt = GroundTruth(small_case / "gt")
    assert coverage(gt, range(8), 8).warnings == []
    found = coverage(gt, range(5), 5)  # the truth of 8 frames for a 5-frame input
    assert found.frames_without_depth == found.frames_without_pose == 0
    assert found.warnings == [
        "ground truth does not match the input: 8 depth map(s) for 5 frame(s); check that the "
        "ground truth belongs to this input",
        "ground truth does not match the input: 8 pose(s) for 5 frame(s); check that the ground "
        "truth belongs to this input",
    ]


def test_case_folder_without_intrinsics_is_read_and_colmap_estimates_the_camera(
    small_case: Path, tmp_path: Path, capsys
) -> None:
    case = copy_case(small_case, tmp_path)
    (case / "intrinsics.json").unlink()
    wd = tmp_path / "wd"
    assert main(["run", str(case), "--workdir", str(wd), "--until", "ingest"]) == 0
    assert "the case has no intrinsics.json: COLMAP estimates the camera" in capsys.readouterr().err
    frames = json.loads((wd / "colon" / "01_ingest" / "frames.json").read_text())
    assert frames["intrinsics"] is None and frames["gt_dir"] == str((case / "gt").resolve())
    assert json.loads((wd / "colon" / "case.json").read_text())["kind"] == "case"


@pytest.mark.parametrize("source", ["gt", "colmap"])
def test_lens_distortion_of_a_case_reaches_cameras_json(
    small_case: Path, tmp_path: Path, source: str
) -> None:
    case = copy_case(small_case, tmp_path)
    k = json.loads((case / "intrinsics.json").read_text())
    k.pop("model")
    dist = [-0.05, 0.01, 0.001, -0.002, 0.003]
    (case / "intrinsics.json").write_text(json.dumps({**k, "dist": dist}))
    wd = tmp_path / "wd"
    args = ["run", str(case), "--workdir", str(wd), "--until", "poses", "--quiet"]
    assert main([*args, "--set", f"poses.source={source}"]) == 0
    cams = json.loads((wd / "colon" / "02_poses" / "cameras.json").read_text())
    assert (cams["source"], cams["model"]) == (source, "FULL_OPENCV")
    assert cams["params"][4:9] == pytest.approx(dist)  # k1 k2 p1 p2 k3 after fx fy cx cy


def test_distortion_under_another_name_is_refused_not_dropped(
    small_case: Path, tmp_path: Path, capsys
) -> None:
    case = copy_case(small_case, tmp_path)
    k = json.loads((case / "intrinsics.json").read_text())
    (case / "intrinsics.json").write_text(json.dumps({**k, "distortion": [-0.1, 0.01, 0, 0]}))
    args = ["run", str(case), "--workdir", str(tmp_path / "wd"), "--until", "ingest"]
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert "has distortion, which endopipe does not read" in err and '"dist"' in err
    assert "Traceback" not in err and not (tmp_path / "wd" / "colon").exists()
