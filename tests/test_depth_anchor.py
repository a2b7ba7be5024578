"""Depth held to what was measured (stages/depth/anchor.py): never worse than the stereo or the
SfM points that trained the field."""

from __future__ import annotations

import numpy as np

from endopipe.stages.depth import anchor
from endopipe.stages.depth.anchor import anchored_depth, sparse_map

H, W = 120, 160


def truth() -> np.ndarray:
    """A tilted wall with a fold: 60-90 mm."""
    v, u = np.mgrid[0:H, 0:W].astype(np.float32)
    return 60.0 + 0.15 * u + 8.0 * np.exp(-((u - 100) ** 2 + (v - 60) ** 2) / 300.0)


def drifted(z: np.ndarray) -> np.ndarray:
    """The field's depth: the right shape, 8% too far on the left, 3% too near on the right."""
    u = np.arange(W, dtype=np.float32)[None, :]
    return z * (1.08 - 0.11 * u / (W - 1))


def abs_rel(a: np.ndarray, b: np.ndarray) -> float:
    m = (a > 0) & (b > 0)
    return float(np.mean(np.abs(a[m] - b[m]) / b[m]))


def test_stereo_is_kept_where_it_matched_and_corrects_the_field_elsewhere() -> None:
    z = truth()
    rng = np.random.default_rng(0)
    stereo = z * (1 + rng.normal(0, 0.01, z.shape)).astype(np.float32)
    stereo[:, :20] = 0.0  # the strip the right eye does not see
    stereo[50:70, 60:90] = 0.0  # a highlight
    out, how = anchored_depth(drifted(z), stereo, paste=True, sigma_px=4.0)
    matched = stereo > 0
    assert np.array_equal(out[matched], stereo[matched])
    field_err = abs_rel(drifted(z)[~matched], z[~matched])
    assert field_err > 0.03
    assert abs_rel(np.where(~matched, out, 0), z) < 0.3 * field_err
    assert how.measured == 1.0 - (~matched).mean()
    assert (out > 0).all()


def test_sparse_points_scale_the_field_locally() -> None:
    z = truth()
    rng = np.random.default_rng(1)
    uv = np.stack([rng.uniform(0, W - 1, 300), rng.uniform(0, H - 1, 300)], 1)
    col, row = np.round(uv[:, 0]).astype(int), np.round(uv[:, 1]).astype(int)
    points = sparse_map(uv, z[row, col] * (1 + rng.normal(0, 0.02, 300)), (H, W))
    assert (points > 0).sum() > 250
    field = drifted(z)
    out, how = anchored_depth(field, points, paste=False, sigma_px=8.0)
    assert abs_rel(field, z) > 0.03
    assert abs_rel(out, z) < 0.01
    assert how.measured == 0.0 and how.corrected == 1.0


def test_too_few_measurements_leave_the_field_as_it_is() -> None:
    z = truth()
    few = np.zeros_like(z)
    few[10, 10:15] = z[10, 10:15]
    out, how = anchored_depth(drifted(z), few, paste=False, sigma_px=8.0)
    assert np.array_equal(out, drifted(z)) and how.median_ratio is None


def test_unknown_field_pixels_stay_unknown_unless_measured() -> None:
    z = truth()
    field = drifted(z)
    field[:10] = 0.0
    stereo = z.copy()
    stereo[:5] = 0.0
    out, _ = anchored_depth(field, stereo, paste=True, sigma_px=4.0)
    assert (out[:5] == 0).all()  # neither the field nor the rig
    assert np.allclose(out[5:10], z[5:10])  # the rig measured it
    out, _ = anchored_depth(field, stereo, paste=False, sigma_px=4.0)
    assert (out[:10] == 0).all()  # points never paste


def test_wide_blurs_on_a_shrunk_image_spread_as_the_direct_ones(monkeypatch) -> None:
    """The spread's coarse scales (wider than the frame) blur a shrunk image: the correction
    they give stays within noise of the direct, hundred-times slower blurs."""
    h, w = 300, 320
    v, u = np.mgrid[0:h, 0:w].astype(np.float32)
    log_ratio = np.log(1.5 + 0.3 * np.sin(u / 40.0) + 0.2 * np.cos(v / 30.0)).astype(np.float32)
    rng = np.random.default_rng(0)
    for n, sigma, tolerance in ((300, 16.0, 1e-3), (50, 32.0, 1e-2)):
        where = np.zeros((h, w), bool)
        where.flat[rng.choice(h * w, n, replace=False)] = True
        values = np.where(where, log_ratio + rng.normal(0, 0.05, (h, w)), 0).astype(np.float32)
        shrunk = anchor.spread(values, where, sigma, 0.1)
        monkeypatch.setattr(anchor, "COARSE_SIGMA_PX", 1e9)  # every blur direct
        direct = anchor.spread(values, where, sigma, 0.1)
        monkeypatch.undo()
        assert float(np.abs(shrunk - direct).max()) < tolerance, (n, sigma)
        assert float(np.ptp(direct)) > 0.3  # the correction does vary over the frame
