"""A recording's scale drift from the scope's light: measured on frames whose truth is known, and
the path redrawn without it; a flat light leaves the path as joined."""

from __future__ import annotations

import numpy as np

from endopipe.recording.join import Joined, JoinedFrame, ScaleKnot, Sim3
from endopipe.recording.light_scale import (
    MAX_WINDOW_DRIFT,
    frame_light,
    largest_window_drift,
    measure,
    redraw_centres,
)

GAMMA = 2.2


def _frames(
    drift: np.ndarray, flat: bool = False, seed: int = 0, exposure: np.ndarray | None = None
) -> list:
    """Keyframes of a tube lit from the camera: true depths 5-60 units, albedo +-30%, an
    inverse-square light through a gamma; depth maps drawn `drift` times too large."""
    rng = np.random.default_rng(seed)
    out = []
    for k, s in enumerate(drift):
        true = rng.uniform(5.0, 60.0, size=(64, 80))
        albedo = rng.uniform(0.7, 1.3, size=true.shape)
        gain = 1.0 if exposure is None else exposure[k]
        linear = gain * albedo * (1.0 if flat else 60.0 / true**2)
        grey = np.clip(linear, 0, 1) ** (1 / GAMMA)
        rgb = np.repeat((grey * 255).astype(np.uint8)[..., None], 3, axis=2)
        found = frame_light(k, rgb, (true * s).astype(np.float32), rng)
        assert found is not None
        out.append(found)
    return out


def test_the_light_measures_a_drift_and_the_redrawn_path_is_even() -> None:
    n = 200
    drift = np.exp(np.linspace(0.15, -0.15, n))  # the path's end drawn 26% smaller than its start
    verdict, log_drift = measure(_frames(drift))
    assert verdict.applied and log_drift is not None
    assert abs(verdict.falloff - 2 / GAMMA) < 0.1  # the falloff found through the gamma
    truth = np.log(drift) - np.log(drift).mean()
    assert np.abs(log_drift - truth)[30:-30].max() < 0.02  # within 2% away from the ends
    assert 1.2 < verdict.drift_range < 1.4
    # equal true steps along a line, drawn with the drift; redrawn, they are equal again
    centres = np.cumsum(np.outer(drift, [0.0, 0.0, 1.0]), axis=0)
    steps = np.linalg.norm(np.diff(redraw_centres(centres, log_drift), axis=0), axis=1)
    assert steps[30:-30].max() / steps[30:-30].min() < 1.04
    assert (np.diff(centres, axis=0)[:, 2].max() / np.diff(centres, axis=0)[:, 2].min()) > 1.25


def test_a_light_that_does_not_fall_with_depth_leaves_the_path_as_joined() -> None:
    verdict, log_drift = measure(_frames(np.ones(60), flat=True))
    assert not verdict.applied and log_drift is None
    assert "falloff" in verdict.reason


def test_a_window_camera_is_placed_on_the_redrawn_path() -> None:
    """Between two knots a camera keeps its offset from the knot before it, scaled as the path
    is there; its depth maps take the same factor as its position."""
    frames = [
        JoinedFrame(source_index=i, window="w000", segment=0, c2w=np.eye(4).tolist())
        for i in (0, 10)
    ]
    joined = Joined(
        frames=frames,
        junctions=[],
        segments=1,
        windows={"w000": Sim3(s=2.0)},
        segment_of={"w000": 0},
        knots=[
            ScaleKnot(source_index=0, segment=0, factor=1.0, centre=[0, 0, 0], redrawn=[0, 0, 0]),
            ScaleKnot(
                source_index=10, segment=0, factor=0.5, centre=[0, 0, 20], redrawn=[0, 0, 15]
            ),
        ],
    )
    own = np.eye(4)
    own[2, 3] = 5.0  # 10 units along the segment's z after the window's similarity
    placed = joined.place("w000", 5, own)
    assert np.allclose(placed[:3, 3], [0, 0, 0.75 * 10])
    assert np.isclose(joined.depth_scale("w000", 5), 2.0 * 0.75)
    own[2, 3] = 11.0  # 2 beyond the second knot
    assert np.allclose(joined.place("w000", 12, own)[:3, 3], [0, 0, 15 + 0.5 * 2])
    assert np.allclose(
        Joined(**{**joined.model_dump(), "knots": []}).place("w000", 5, own)[2, 3], 22
    )


def test_an_exposure_that_changes_is_not_taken_for_a_drift() -> None:
    """A scope whose exposure halves mid-recording: the light reads it as a scale change far
    steeper inside one window than SfM drifts, and the gate names that window; a true drift of
    5% a window passes."""
    n, per_window = 200, 40
    windows = [f"w{k // per_window:03d}" for k in range(n)]
    exposure = np.where(np.arange(n) < 100, 1.0, 0.5)
    _, jumped = measure(_frames(np.ones(n), exposure=exposure))
    name, span = largest_window_drift(jumped, windows)
    assert span > MAX_WINDOW_DRIFT and name in ("w001", "w002")
    _, drifted = measure(_frames(np.exp(np.linspace(0.1, -0.1, n))))
    assert largest_window_drift(drifted, windows)[1] < MAX_WINDOW_DRIFT
