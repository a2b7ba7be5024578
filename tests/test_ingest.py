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
