"""Tool masks: a case folder's masks/ read by number in either polarity (a mostly-white mask
refused in one line with the flag that flips it), their pixels out of the usable mask, kept per
frame with their share; and the detector, which marks grey metal reaching the view's edge and
nothing on tissue."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from endopipe.cli import main
from endopipe.pipeline.errors import InputError
from endopipe.stages.ingest.config import ToolsConfig
from endopipe.stages.ingest.tool_detect import detect_tools
from endopipe.stages.ingest.tools import read_tool_mask
from endopipe.stages.ingest.view import IngestView
from endopipe.stages.io.sources import open_input

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
W, H = 64, 48


def pink(rng: np.random.Generator) -> np.ndarray:
    """A textured, saturated tissue frame (RGB)."""
    base = np.array([190, 60, 70], float) + rng.integers(-40, 40, (H, W, 1))
    return np.clip(base, 0, 255).astype(np.uint8)


def case_with_masks(root: Path, tool_share: float, value: int = 255) -> Path:
    """A case folder of 6 frames; masks/ for frames 1..5 marking the left `tool_share` (value
    `value` on the tool, 0 elsewhere); frame 0 has no mask file (no tool in view)."""
    case = root / "case"
    for sub in ("frames", "masks", "gt"):
        (case / sub).mkdir(parents=True)
    rng = np.random.default_rng(1)
    mask = np.zeros((H, W), np.uint8)
    mask[:, : round(W * tool_share)] = value
    for i in range(6):
        cv2.imwrite(str(case / "frames" / f"{i:06d}.png"), pink(rng)[..., ::-1])
        if i:
            cv2.imwrite(str(case / "masks" / f"{i:06d}.png"), mask)
    return case


def ingest(case: Path, wd: Path, *sets: str) -> int:
    args = ["run", str(case), "--workdir", str(wd), "--until", "ingest", "--quiet"]
    extra = [a for s in ("ingest.drop_duplicates=false", *sets) for a in ("--set", s)]
    return main([*args, *extra])


def test_masks_are_matched_by_number_and_read_at_the_working_size(tmp_path: Path) -> None:
    case = case_with_masks(tmp_path, 0.25, value=1)  # a 0/1 mask reads as 0/255
    masks = open_input(case).tool_masks
    assert masks is not None and sorted(masks.files) == [1, 2, 3, 4, 5]
    tool = read_tool_mask(masks.file(1), (32, 24))
    assert tool.shape == (24, 32) and tool[:, :8].all() and not tool[:, 8:].any()


def test_a_mostly_white_mask_is_refused_in_one_line_naming_the_flag(tmp_path, capsys) -> None:
    case = case_with_masks(tmp_path, 0.8)
    with pytest.raises(InputError, match=r"000001.png marks 80% .*ingest.tools.polarity="):
        read_tool_mask(case / "masks" / "000001.png", (W, H))
    assert ingest(case, tmp_path / "wd") != 0
    err = capsys.readouterr().err.strip()
    assert "ingest.tools.polarity=black_is_tool" in err and len(err.splitlines()) == 1
    # told the polarity, the same masks read as 0 = tool: the left 80% is tissue
    tool = read_tool_mask(case / "masks" / "000001.png", (W, H), "black_is_tool")
    assert tool.mean() == pytest.approx(0.2, abs=0.02)


def test_tool_pixels_leave_the_usable_mask_and_are_kept_per_frame(tmp_path: Path) -> None:
    case = case_with_masks(tmp_path, 0.25)
    assert ingest(case, tmp_path / "wd") == 0
    view = IngestView(tmp_path / "wd" / "case" / "01_ingest")
    assert not view.tool_mask(0).any()  # no mask file: no tool in that frame
    tool = view.tool_mask(1)
    assert tool[:, :16].all() and not tool[:, 16:].any()
    assert (view.mask(1)[tool] == 0).all() and (view.mask(1)[:, 20:] > 0).mean() > 0.9
    s = view.summary
    assert s.tool_polarity == "255 = tool" and s.frames_with_tools == 5
    assert s.mean_tool_fraction == pytest.approx(0.25 * 5 / 6)
    assert s.max_tool_fraction == pytest.approx(0.25)
    assert view.frame(1).tool_share == pytest.approx(0.25)


def test_the_detector_marks_grey_metal_from_the_edge_and_not_tissue() -> None:
    rng = np.random.default_rng(2)
    cfg, fov = ToolsConfig(), np.full((H, W), 255, np.uint8)
    rgb = pink(rng)
    assert not detect_tools(rgb, fov, cfg).any()
    metal = rgb.copy()
    metal[18:30, 30:] = (130, 138, 150)  # a cool grey shaft entering from the right
    found = detect_tools(metal, fov, cfg)
    assert found[20:28, 34:].all() and not found[:, :26].any()
    island = rgb.copy()
    island[18:30, 20:40] = (130, 138, 150)  # grey, but not reaching the edge: not a tool
    assert not detect_tools(island, fov, cfg).any()
    fat = rgb.copy()
    fat[18:30, 30:] = (215, 200, 185)  # pale but warm: fat, a washed-out wall
    assert not detect_tools(fat, fov, cfg).any()


@pytest.mark.skipif(not (DATA / "endonerf_cutting").is_dir(), reason="needs ../shared/data")
def test_the_detector_on_real_frames_with_and_without_tools() -> None:
    """EndoNeRF's cutting clip (a da Vinci instrument over a sixth of frame 75) and a C3VD
    frame (no tool): measured in docs/experiments.md."""
    cap = cv2.VideoCapture(str(DATA / "endonerf_cutting" / "cutting_gt.mp4"))
    cap.set(cv2.CAP_PROP_POS_FRAMES, 75)
    ok, bgr = cap.read()
    assert ok
    clips = {"cutting": bgr, "c3vd": cv2.imread(str(DATA / "c3vd_v3_preview/rgb/0000.png"))}
    shares = {}
    for name, img in clips.items():
        h, w = img.shape[:2]
        small = cv2.resize(img, (320, round(320 * h / w)), interpolation=cv2.INTER_AREA)
        rgb = cv2.cvtColor(small, cv2.COLOR_BGR2RGB)
        shares[name] = detect_tools(
            rgb, np.full(rgb.shape[:2], 255, np.uint8), ToolsConfig()
        ).mean()
    assert 0.1 < shares["cutting"] < 0.25 and shares["c3vd"] == 0.0


def test_detection_is_turned_off_by_the_word_off() -> None:
    """`--set ingest.tools.detect=off` reaches the config as YAML's false."""
    assert ToolsConfig.model_validate({"detect": False}).detect == "off"
    assert ToolsConfig.model_validate({"detect": "auto"}).detect == "auto"
