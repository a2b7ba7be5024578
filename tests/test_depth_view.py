"""05_depth read back through DepthView, and the preview's scaled error (shared with the report)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from endopipe.stages.depth.preview import error_map, scaled_error
from endopipe.stages.depth.view import DepthMetrics, DepthView
from endopipe.stages.metrics.depth import depth_sequence_metrics


def test_scaled_error_undoes_the_unknown_scale() -> None:
    rng = np.random.default_rng(0)
    gt = rng.uniform(5, 50, (24, 32)).astype(np.float32)
    gt[:4] = 0  # invalid ground truth
    depth = gt / 7.0
    valid = gt > 0
    err, scale, shift = scaled_error(depth, gt, valid)
    assert abs(scale - 7.0) < 1e-4 and shift == 0.0
    assert np.nanmax(err) < 1e-5 and np.isnan(err[~valid]).all()
    err, scale, shift = scaled_error(depth * 2 + 3, gt, valid, affine=True)  # relative GT
    assert abs(scale - 3.5) < 1e-3 and abs(shift + 10.5) < 1e-2 and np.nanmax(err) < 1e-4
    wrong = depth.copy()
    wrong[10:, :16] *= 1.5  # half the valid pixels 50 % too deep
    err, _, _ = scaled_error(wrong, gt, valid)
    assert np.nanmax(err) > 0.3
    coloured = error_map(wrong, gt)
    assert coloured.shape == (24, 32, 3) and (coloured[:4] == 0).all()


def test_view_reads_depth_opacity_and_metrics(tmp_path: Path) -> None:
    (tmp_path / "depth").mkdir()
    (tmp_path / "opacity").mkdir()
    maps = {i: np.full((6, 8), float(i + 1), np.float32) for i in (2, 5, 11)}
    for i, d in maps.items():
        np.save(tmp_path / "depth" / f"{i:06d}.npy", d)
    np.save(tmp_path / "opacity" / "000005.npy", np.ones((6, 8), np.float32))
    view = DepthView(tmp_path)
    assert view.indices == [2, 5, 11] and view.metrics is None
    np.testing.assert_array_equal(view.depth(11), maps[11])
    assert view.opacity(5) is not None and view.opacity(2) is None
    assert view.has_depth(5) and not view.has_depth(3)

    gt = [np.full((6, 8), 2.0 * (i + 1), np.float32) for i in maps]
    metrics = depth_sequence_metrics(list(maps.values()), gt, None, list(maps))
    metrics |= {"gt_kind": "exact", "heldout_frames": [2], "heldout_psnr": 21.5}
    text = json.dumps(metrics, indent=2)
    (tmp_path / "metrics.json").write_text(text)
    read = DepthView(tmp_path).metrics
    assert isinstance(read, DepthMetrics)
    assert read.gt_kind == "exact" and read.frames == 3 and read.heldout_psnr == 21.5
    assert abs(read.sequence_scaled.scale - 2.0) < 1e-6
    assert read.median_scaled.abs_rel < 1e-6
    assert json.dumps(read.model_dump(mode="json", exclude_none=True), indent=2) == text


def test_holes_show_in_a_colour_no_depth_or_error_has() -> None:
    from endopipe.stages.depth.preview import (
        DEPTH_CMAP,
        ERROR_CMAP,
        NO_DEPTH,
        apply_cmap,
        colourise,
        label_panel,
    )

    gt = np.linspace(10, 40, 24 * 32, dtype=np.float32).reshape(24, 32)
    depth = gt / 3
    depth[8:12, 10:20] = 0.0  # a hole: the field found no surface here
    inside = np.ones_like(gt, bool)
    inside[:, :2] = False  # outside the scope's field of view
    shown = colourise(depth, 3, 14, inside=inside)
    assert (shown[8:12, 10:20] == NO_DEPTH).all()
    assert (shown[:, :2] == 0).all()  # outside: black, not a hole
    assert not (shown[12:, 2:] == NO_DEPTH).all(axis=-1).any()  # no depth pixel looks like one
    for cmap in (DEPTH_CMAP, ERROR_CMAP):
        every = apply_cmap(np.linspace(0, 1, 256)[None], cmap)[0].astype(float)
        assert np.linalg.norm(every - np.array(NO_DEPTH), axis=1).min() > 60
    errors = error_map(depth, gt, inside=inside)
    assert (errors[8:12, 10:20] == NO_DEPTH).all() and (errors[:, :2] == 0).all()
    assert (errors[12:, 2:] != NO_DEPTH).any(axis=-1).all()
    legend = label_panel(shown, "depth, grey = no depth", (DEPTH_CMAP, "3", "14"))

    def holes(img: np.ndarray) -> int:
        return int((img == NO_DEPTH).all(axis=-1).sum())

    assert holes(legend) > holes(shown)  # and the legend shows the hole's colour


def test_the_far_bakes_ramp_gives_the_weight_quartiles_of_a_linear_wall() -> None:
    """A density rising linearly from zero at t = 10 (slope m) has optical depth m (t - 10)^2 / 2:
    the transmittance is 3/4, 1/2, 1/4 at t = 10 + sqrt(2 ln(4/3) / m), ... exactly; three level
    crossings are all the ramp needs, wherever the quartiles fall among them."""
    import numpy as np

    from endopipe.stages.nerf.baked import ramp_quantiles

    taus = np.log([4 / 3, 2.0, 4.0])
    for m, levels in ((0.5, np.array([0.1, 0.5, 1.0])), (40.0, np.array([0.4, 2.0, 4.0]))):
        t = (10.0 + levels / m)[:, None]  # where the density crosses each level
        got = ramp_quantiles(t, levels, taus)[:, 0]
        assert np.allclose(got, 10.0 + np.sqrt(2 * taus / m), rtol=0, atol=1e-9), (m, got)
    # a gentle ramp (haze) spreads the weight over far more of the depth than a steep wall
    spread = {}
    for m in (0.01, 50.0):
        levels = np.array([0.1, 0.5, 1.0])
        q = ramp_quantiles((30.0 + levels / m)[:, None], levels, taus)[:, 0]
        spread[m] = (q[2] - q[0]) / q[1]
    assert spread[50.0] < 0.01 < 0.15 < spread[0.01], spread
