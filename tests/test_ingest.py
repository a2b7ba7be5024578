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
    from endopipe.commands.synth import SynthConfig, generate_case

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
        "frames", "intrinsics", "width", "height", "source", "gt_dir", "fov_shape", "dropped"
    ]  # fmt: skip
    assert list(raw["frames"][0]) == ["index", "source_index", "time_s", "file", "mask"]
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
