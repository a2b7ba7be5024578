"""Synthetic cases whose anatomy moves: a breathing wall, a patch pulled by a tool in view, a
still camera, the tool's masks, EndoNeRF's layout, and rigid cases unchanged byte for byte."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from endopipe.export.endonerf import read_endonerf
from endopipe.export.endonerf_sink import EndoNerfSink
from endopipe.pipeline.errors import EndopipeError
from endopipe.synth import Layout, SynthConfig, generate_case
from endopipe.synth.generate import Setup, prepare

TINY = {"width": 96, "height": 80, "fps": 25}
PULL = SynthConfig(shape="cavity", frames=10, deform="pull", still_camera=True, **TINY)
BOTH = Layout("endonerf", EndoNerfSink, subfolder="endonerf")

#: SHA-256 over every file (relative path, then bytes) of rigid 3-frame 64x48 cases, as the
#: generator wrote them before the anatomy could move: deform=none must keep these bytes.
RIGID_DIGESTS = {
    "colon": "6c154a0157bdbc8e4348716a7fec1f10a5251e8af937bc165cbcb60da847b7bd",
    "cavity": "215b95cd87fea10b972bd5dd13d0b34ad274df01c38a25d1b00593d91ad5bff7",
}


def folder_digest(folder: Path) -> str:
    h = hashlib.sha256()
    for p in sorted(folder.rglob("*")):
        if p.is_file():
            h.update(str(p.relative_to(folder)).encode())
            h.update(p.read_bytes())
    return h.hexdigest()


def depths(case: Path) -> np.ndarray:
    return np.stack([np.load(p) for p in sorted((case / "gt" / "depth").glob("*.npy"))])


@pytest.fixture(scope="module")
def pull_case(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("pull") / "case"
    generate_case(out, PULL, layout=BOTH)
    return out


@pytest.fixture(scope="module")
def pull_setup() -> Setup:
    return prepare(PULL)


@pytest.mark.parametrize("shape", sorted(RIGID_DIGESTS))
def test_rigid_case_keeps_its_bytes(tmp_path: Path, shape: str) -> None:
    generate_case(tmp_path / shape, SynthConfig(shape=shape, frames=3, width=64, height=48))
    assert folder_digest(tmp_path / shape) == RIGID_DIGESTS[shape]
    assert not (tmp_path / shape / "masks").exists()


def test_breathing_moves_the_whole_wall_and_comes_back(tmp_path: Path) -> None:
    """Period 0.4 s at 25 fps: frame 5 is the peak (radius x 1.05), frame 10 the rest again."""
    cfg = SynthConfig(
        shape="cavity",
        frames=11,
        deform="breathe",
        deform_amplitude=0.05,
        breathe_period_s=0.4,
        still_camera=True,
        **TINY,
    )
    generate_case(tmp_path / "b", cfg)
    d = depths(tmp_path / "b")
    valid = (d[0] > 0) & (d[5] > 0)
    rel = d[5][valid] / d[0][valid] - 1.0
    assert np.mean(rel > 0.005) > 0.95  # the wall moved out nearly everywhere
    assert 0.5 * 0.05 < np.median(rel) < 2.5 * 0.05  # by about the amplitude
    np.testing.assert_allclose(d[10], d[0], atol=1e-3)  # a full period: back at rest
    meta = json.loads((tmp_path / "b" / "gt" / "synth.json").read_text())
    assert meta["deform"]["kind"] == "breathe" and meta["deform"]["amplitude"] == 0.05
    assert "frame 0" in meta["deform"]["mesh"]


def test_still_camera_has_one_pose(pull_case: Path) -> None:
    poses = np.array(json.loads((pull_case / "gt" / "poses.json").read_text())["poses"])
    assert len(poses) == PULL.frames and np.all(poses == poses[0])


def test_pull_moves_the_wall_only_around_the_spot(pull_setup: Setup) -> None:
    """The tissue alone (no tool): changed at the peak by about the amplitude, and only where
    the rest wall lies within the pulled patch (plus how far it moves)."""
    pull = pull_setup.disp
    peak = int(np.argmax([pull.strength(pull_setup.time(i)) for i in range(PULL.frames)]))
    rest, moved = pull_setup.trace(0), pull_setup.trace(peak)
    diff = np.abs(moved.depth - rest.depth)
    assert 0.5 * pull.amplitude < diff.max() < 2.0 * pull.amplitude
    near = np.zeros(rest.depth.shape, bool)
    near[rest.valid] = np.linalg.norm(rest.points - pull.spot, axis=1) < pull.radius + pull.reach
    assert diff[~near].max() < 1e-4
    assert diff[near].max() > 1.0


def test_tool_mask_is_where_the_depth_is_the_tools(pull_case: Path, pull_setup: Setup) -> None:
    d = depths(pull_case)
    covered = []
    for i in (0, 3, PULL.frames - 1):
        mask = cv2.imread(str(pull_case / "masks" / f"{i:06d}.png"), cv2.IMREAD_UNCHANGED)
        assert mask.dtype == np.uint8 and set(np.unique(mask)) <= {0, 255}
        tissue = pull_setup.trace(i).depth.astype(np.float32)
        np.testing.assert_array_equal(mask == 255, d[i] != tissue)
        assert np.all(d[i][mask == 255] < tissue[mask == 255])  # the tool is in front
        covered.append(float(np.mean(mask == 255)))
    assert 0.02 < covered[1] < 0.5  # the grasping tool is in view, not filling it
    # Low saturation: the tool's pixels are grey, the tissue's red.
    rgb = cv2.imread(str(pull_case / "frames" / "000003.png"))[:, :, ::-1].astype(float)
    mask = cv2.imread(str(pull_case / "masks" / "000003.png"), cv2.IMREAD_UNCHANGED) == 255
    spread = rgb.max(axis=2) - rgb.min(axis=2)
    assert np.median(spread[mask]) < 0.5 * np.median(spread[~mask])


def test_pulled_depth_changes_only_near_the_spot_or_under_the_tool(
    pull_case: Path, pull_setup: Setup
) -> None:
    d = depths(pull_case)
    pull = pull_setup.disp
    rest = pull_setup.trace(0)
    near = np.zeros(rest.depth.shape, bool)
    near[rest.valid] = np.linalg.norm(rest.points - pull.spot, axis=1) < pull.radius + pull.reach
    masks = np.stack(
        [
            cv2.imread(str(p), cv2.IMREAD_UNCHANGED) == 255
            for p in sorted((pull_case / "masks").glob("*.png"))
        ]
    )
    for i in range(1, PULL.frames):
        changed = np.abs(d[i] - d[0]) > 1e-4
        assert not np.any(changed & ~near & ~masks[i] & ~masks[0])


def test_endonerf_layout_round_trips(pull_case: Path) -> None:
    enerf = pull_case / "endonerf"
    arr = np.load(enerf / "poses_bounds.npy")
    assert arr.shape == (PULL.frames, 17)
    hwf = arr[:, :15].reshape(-1, 3, 5)[:, :, 4]
    intr = json.loads((pull_case / "intrinsics.json").read_text())
    np.testing.assert_allclose(hwf, [[intr["height"], intr["width"], intr["fx"]]] * PULL.frames)
    bounds, c2ws = read_endonerf(enerf, "llff")
    truth = np.array(json.loads((pull_case / "gt" / "poses.json").read_text())["poses"])
    np.testing.assert_allclose(np.array(c2ws), truth, atol=1e-12)
    d = depths(pull_case)
    assert np.all(bounds[:, 0] < bounds[:, 1]) and np.all(bounds[:, 0] >= d[d > 0].min() - 1e-6)
    meta = json.loads((enerf / "endonerf.json").read_text())
    for i in range(PULL.frames):
        tool = cv2.imread(str(pull_case / "masks" / f"{i:06d}.png"), cv2.IMREAD_UNCHANGED)
        mask = cv2.imread(str(enerf / "masks" / f"frame-{i:06d}.mask.png"), cv2.IMREAD_UNCHANGED)
        np.testing.assert_array_equal(mask, tool)  # EndoNeRF's polarity: 255 = tool, excluded
        png = cv2.imread(str(enerf / "depth" / f"frame-{i:06d}.depth.png"), cv2.IMREAD_UNCHANGED)
        assert png.dtype == np.uint16
        np.testing.assert_allclose(png / meta["depth_scale"], d[i], atol=0.51 / meta["depth_scale"])
        a = cv2.imread(str(enerf / "images" / f"frame-{i:06d}.color.png"))
        np.testing.assert_array_equal(a, cv2.imread(str(pull_case / "frames" / f"{i:06d}.png")))


def test_endonerf_layout_instead_of_the_frames(tmp_path: Path) -> None:
    only = Layout("endonerf", EndoNerfSink)
    cfg = SynthConfig(shape="colon", frames=3, width=64, height=48)
    generate_case(tmp_path / "e", cfg, layout=only)
    names = {p.name for p in (tmp_path / "e").iterdir()}
    assert names == {"images", "masks", "depth", "poses_bounds.npy", "endonerf.json", "gt"}
    masks = [cv2.imread(str(p), cv2.IMREAD_UNCHANGED) for p in (tmp_path / "e" / "masks").iterdir()]
    assert len(masks) == 3 and all(m.max() == 0 for m in masks)  # no tool: nothing excluded
    # A lens the pinhole-only layout cannot carry is refused before anything is rendered.
    with pytest.raises(EndopipeError, match="pinhole-only"):
        generate_case(tmp_path / "lens", cfg.model_copy(update={"lens": "barrel"}), layout=only)
    assert not any(tmp_path.glob(".lens*")) and not (tmp_path / "lens").exists()


def test_a_stereo_endonerf_case_has_matched_depth_and_exact_truth_apart(tmp_path: Path) -> None:
    """--layout endonerf --stereo: depth/ is what the matcher finds on the rendered pair (holes,
    errors), as EndoNeRF's own; the exact depth stays in gt/. Run, it
    supervises in mm and is no copy of the truth; without a right eye depth/ is the truth and
    the run says its scores are no check."""
    from endopipe.cli import main
    from endopipe.commands.synth import other_layout
    from endopipe.stages.ingest.view import IngestView

    cfg = PULL.model_copy(update={"frames": 6, "width": 160, "height": 128})
    stereo = cfg.model_copy(update={"stereo_baseline_mm": 5.0})
    generate_case(tmp_path / "s", stereo, layout=other_layout("endonerf", 5.0))
    generate_case(tmp_path / "x", cfg, layout=other_layout("endonerf"))
    meta = json.loads((tmp_path / "s" / "endonerf.json").read_text())
    assert "StereoSGBM" in meta["depth"] and meta["units"] == "mm"
    png = cv2.imread(str(tmp_path / "s" / "depth" / "frame-000005.depth.png"), -1)
    truth = np.load(tmp_path / "s" / "gt" / "depth" / "000005.npy")
    depth = png / meta["depth_scale"]
    matched = depth > 0
    assert 0.3 < matched.mean() < 0.98
    err = np.abs(depth[matched] - truth[matched]) / truth[matched]
    assert 0.002 < np.median(err) < 0.05  # a measurement: near the truth, not the truth
    views = {}
    for name in ("s", "x"):
        args = ["run", str(tmp_path / name), "--workdir", str(tmp_path / "wd"), "--quiet"]
        assert main([*args, "--until", "ingest"]) == 0
        views[name] = IngestView(tmp_path / "wd" / name / "01_ingest")
        assert views[name].has_stereo and views[name].file.stereo.baseline_mm is None
    assert views["s"].truth_supervised(views["s"].ground_truth()) is None
    assert views["x"].truth_supervised(views["x"].ground_truth()) is not None
