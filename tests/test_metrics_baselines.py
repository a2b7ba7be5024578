"""Coverage and the two guesses (stages.metrics.baselines) on depth with exact truth, through
the depth stage's own evaluation, and the report's sentence when ours does not beat a guess."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import numpy as np
from scipy.stats import spearmanr

from endopipe.stages.depth.evaluate import evaluate
from endopipe.stages.metrics.baselines import brightness_guess, radial_guess
from endopipe.stages.metrics.depth import (
    affine_invariant_metrics,
    depth_frame_metrics,
    depth_sequence_metrics,
)
from endopipe.stages.report.config import ReportConfig
from endopipe.stages.report.load import load_case
from endopipe.stages.report.render import ReportInfo
from endopipe.stages.report.sections import section_depth

H, W = 60, 80
CX, CY = 46.0, 27.0  # off the image centre: the guess must use the principal point


def disc(cx: float = CX, cy: float = CY, radius: float = 27.0) -> np.ndarray:
    """A scope's round field of view."""
    v, u = np.mgrid[0:H, 0:W]
    return np.hypot(u - cx, v - cy) <= radius


def shaded(z: np.ndarray) -> np.ndarray:
    """The frame a light at the camera gives: I = (z_min / z)² in 0..1, as uint8 RGB."""
    i = (z.min() / z) ** 2
    return np.repeat((255 * i)[..., None], 3, axis=2).round().astype(np.uint8)


def slanted_wall() -> np.ndarray:
    """A smooth, non-radial scene: a wall slanting away to the right and down (mm)."""
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    return (20 + 0.4 * u + 0.15 * v).astype(np.float32)


@dataclass
class Frames:
    """What `evaluate` reads of the ingest view: the grid, the field of view, the images."""

    images: dict[int, np.ndarray]
    inside: np.ndarray
    tool: np.ndarray | None = None  # every frame's tool mask
    height: int = H
    width: int = W

    def fov(self) -> np.ndarray:
        return self.inside.astype(np.uint8) * 255

    def image(self, i: int) -> np.ndarray:
        return self.images[i]

    def tool_mask(self, i: int) -> np.ndarray | None:
        return self.tool


def scored(
    ours: np.ndarray,
    gt: np.ndarray,
    image: np.ndarray,
    kind: str = "exact",
    tool: np.ndarray | None = None,
) -> dict:
    """metrics.json of the depth stage for a one-frame sequence (through `evaluate`)."""
    frames = Frames({0: image}, disc(), tool)
    truth = SimpleNamespace(kind=kind)
    return evaluate(truth, frames, {0: ours}, {0: gt}, {}, principal=(CX, CY))


# --- coverage ---------------------------------------------------------------------------------


def test_a_perfect_depth_covers_everything_and_beats_both_guesses() -> None:
    gt = slanted_wall()
    texture = np.random.default_rng(0).integers(0, 256, (H, W, 3), dtype=np.uint8)
    m = scored(gt.copy(), gt, texture)
    assert m["median_scaled"]["coverage"] == 1.0 and m["median_scaled"]["abs_rel"] < 1e-6
    assert m["per_frame"][0]["median_scaled"]["coverage"] == 1.0
    for name in ("radial", "brightness"):
        guess = m["baselines"][name]
        assert set(guess["median_scaled"]) == set(m["median_scaled"])  # the same keys as ours
        assert guess["median_scaled"]["abs_rel"] > 0.05
        assert guess["median_scaled"]["delta1"] < m["median_scaled"]["delta1"]


def test_a_tool_is_left_out_of_every_score_and_its_share_said() -> None:
    """On a tool the truth is the tool (near), ours the tissue under it: scored there, ours
    would be far off; left out, ours and the guesses are scored on the tissue alone."""
    tissue = slanted_wall()
    tool = np.zeros((H, W), bool)
    tool[20:40, 30:60] = True
    truth = np.where(tool, 8.0, tissue).astype(np.float32)  # the tool, nearer than the wall
    texture = np.random.default_rng(0).integers(0, 256, (H, W, 3), dtype=np.uint8)
    m = scored(tissue.copy(), truth, texture, tool=tool)
    assert m["median_scaled"]["abs_rel"] < 1e-6  # ours is right wherever tissue is seen
    assert m["tool_share_left_out"] == (tool & disc()).sum() / disc().sum()
    untouched = scored(tissue.copy(), tissue, texture, tool=tool)["baselines"]
    for name in ("radial", "brightness"):  # the guesses on the same tissue pixels
        assert m["baselines"][name]["median_scaled"] == untouched[name]["median_scaled"]
    on_tool = scored(tissue.copy(), truth, texture)  # no tool masks: the tool is scored
    assert on_tool["tool_share_left_out"] is None
    assert on_tool["median_scaled"]["abs_rel"] > 0.2


def test_holes_lower_coverage_and_the_rest_is_scored_alone() -> None:
    rng = np.random.default_rng(1)
    gt = slanted_wall()
    inside = disc()
    full = gt * 2.5 * rng.uniform(0.9, 1.1, gt.shape).astype(np.float32)
    asked = np.flatnonzero(inside)
    holes = rng.choice(asked, size=round(0.3 * asked.size), replace=False)
    ours = full.copy()
    ours.flat[holes] = 0.0
    kept = inside.copy()
    kept.flat[holes] = False
    m = depth_frame_metrics(ours, gt, inside)
    assert abs(m["coverage"] - 0.7) < 1 / asked.size
    alone = depth_frame_metrics(full[kept], gt[kept])  # the covered pixels, nothing else
    for key in ("abs_rel", "sq_rel", "rmse", "rmse_log", "delta1", "scale"):
        assert abs(m[key] - alone[key]) < 1e-9, key
    # A frame with no depth at all counts as 0 in the mean coverage, not as missing.
    seq = depth_sequence_metrics([ours, np.zeros_like(ours)], [gt, gt], [inside, inside])
    assert abs(seq["median_scaled"]["coverage"] - 0.35) < 1e-3
    assert abs(seq["median_scaled"]["abs_rel"] - alone["abs_rel"]) < 1e-9
    assert abs(affine_invariant_metrics(ours, gt, inside)["coverage"] - 0.7) < 1e-3


def test_guesses_are_scored_on_our_pixels_only() -> None:
    gt = slanted_wall()
    ours = gt.copy()
    ours[:, : W // 2] = 0.0  # ours left the left half out
    m = scored(ours, gt, shaded(gt))
    cover = m["median_scaled"]["coverage"]
    assert 0.3 < cover < 0.7
    assert m["baselines"]["radial"]["median_scaled"]["coverage"] == cover


# --- the guesses ------------------------------------------------------------------------------


def test_the_radial_guess_is_exact_on_a_radial_scene() -> None:
    inside = disc()
    v, u = np.mgrid[0:H, 0:W]
    r = np.hypot(u - CX, v - CY)
    truth = 3.0 * (r[inside].max() - r + 1) + 5.0  # radial, up to scale and shift
    truth = np.where(inside, truth, 0).astype(np.float32)
    guess = radial_guess(H, W, CX, CY, inside)
    assert guess.min() > 0
    m = affine_invariant_metrics(guess, truth, inside)
    assert m["abs_rel"] < 1e-5 and m["spearman"] > 1 - 1e-9
    # Through the depth stage's evaluation, with the principal point handed over.
    noisy = truth * np.random.default_rng(2).uniform(0.8, 1.2, truth.shape).astype(np.float32)
    stage = scored(noisy, truth, shaded(np.where(inside, truth, 1)), kind="relative")
    assert stage["baselines"]["radial"]["affine_invariant"]["spearman"] > 1 - 1e-9
    off_centre = affine_invariant_metrics(radial_guess(H, W, W / 2, H / 2, inside), truth, inside)
    assert off_centre["spearman"] < 0.99  # the principal point matters


def test_the_brightness_guess_recovers_the_depth_ranking_under_inverse_square_light() -> None:
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    z = 15 + 10 * np.exp(-((u - 30) ** 2 + (v - 35) ** 2) / (2 * 18**2))  # a smooth bulge
    guess = brightness_guess(shaded(z))
    assert spearmanr(guess.ravel(), z.ravel()).statistic > 0.99
    # Light that grows with depth (no inverse square) gives the ranking upside down.
    backwards = brightness_guess(np.repeat((255 * (z / z.max()) ** 2)[..., None], 3, 2))
    assert spearmanr(backwards.ravel(), z.ravel()).statistic < -0.99


# --- the report says it in words -------------------------------------------------------------


def section(tmp_path: Path, metrics: dict, depth: np.ndarray) -> str:
    folder = tmp_path / "05_depth"
    (folder / "depth").mkdir(parents=True)
    np.save(folder / "depth" / "000000.npy", depth)
    (folder / "metrics.json").write_text(json.dumps(metrics))
    data = load_case(tmp_path, {"depth": folder}, ReportConfig(max_preview_frames=1))
    return section_depth(data, ReportInfo(gt_kind=metrics.get("gt_kind", "none")))


def test_the_report_says_when_ours_is_no_better_than_a_guess(tmp_path: Path) -> None:
    inside = disc()
    v, u = np.mgrid[0:H, 0:W]
    gt = np.where(inside, 2 * radial_guess(H, W, CX, CY, inside), 0)  # the centre is far
    ours = np.where(inside, 20 + 0.5 * u, 0).astype(np.float32)  # a wall: wrong
    metrics = scored(ours, gt, shaded(np.where(inside, gt, 1)))
    page = section(tmp_path / "bad", metrics, ours)
    assert "On this case our depth is no more accurate than the radial guess" in page
    assert "Against two guesses" in page and "Coverage" in page

    relative = scored(ours, gt, shaded(np.where(inside, gt, 1)), kind="relative")
    page = section(tmp_path / "relative", relative, ours)
    assert "our depth ranks pixels no better than the radial guess" in page

    tie = scored(gt.copy(), gt, shaded(np.where(inside, gt, 1)))  # ours exact, radial too
    assert "no more accurate than the radial guess" in section(tmp_path / "tie", tie, gt)

    wall = np.where(inside, slanted_wall(), 0)  # a scene that is not radial, and ours exact
    good = scored(wall.copy(), wall, shaded(slanted_wall()))
    page = section(tmp_path / "good", good, wall)
    assert "no more accurate than" not in page and "Ours beats every guess" in page
