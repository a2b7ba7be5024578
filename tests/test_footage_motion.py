"""The footage's motion, judged before SfM: a still camera over moving tissue is told from a
moving camera by the motion's structure (how many corners stayed put, against what one global
motion explains), not its amount: on corner motions made here, on frames made here (known
motion) and on the real clips (known to be still or moving from their provenance)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from endopipe.stages.poses.config import MotionConfig
from endopipe.stages.poses.motion import (
    FootageMotion,
    footage_fps,
    judge_motion,
    judge_spans,
    span_motion,
)


def texture(h: int, w: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    small = rng.random((h // 6, w // 6)).astype(np.float32)
    return (cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC).clip(0, 1) * 200 + 30).astype(
        np.uint8
    )


def warp(img: np.ndarray, dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
    h, w = img.shape
    v, u = np.mgrid[0:h, 0:w].astype(np.float32)
    mx, my = (u - dx).astype(np.float32), (v - dy).astype(np.float32)
    return cv2.remap(img, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)


def clip(kind: str, n: int = 40, h: int = 128, w: int = 160) -> list[np.ndarray]:
    """`pan`: the view slides 1.5 px a frame (a moving camera); `creep`: it slides 0.12 px a
    frame (a slow camera: 3 px, 1.5% of the diagonal, in a second); `breathe`: a still view
    whose middle swells and settles (up to 3 px, period 20 frames); `pull`: a still view whose
    right 70% is dragged right, up to 0.45 px more each frame (11 px, 5.5% of the diagonal, in
    a second) and its rows most, and up or down by where it lies, while the left stays put;
    `still`: nothing moves."""
    base = texture(h + 8, w + 80)
    v, u = np.mgrid[0:h, 0:w].astype(np.float32)
    bump = np.exp(-(((u - w / 2) / (w / 4)) ** 2 + ((v - h / 2) / (h / 4)) ** 2))
    grip = np.clip((u - 0.3 * w) / (0.1 * w), 0, 1)  # the pulled part: 0 left of 0.3 w
    drag_x = 0.45 * grip * (0.5 + 0.5 * np.sin(np.pi * v / h))  # px a frame
    drag_y = 0.3 * grip * np.sin(2 * np.pi * (u - 0.3 * w) / (0.7 * w))
    out = []
    for i in range(n):
        if kind == "pan":
            x0 = int(round(1.5 * i))
            out.append(np.ascontiguousarray(base[:h, x0 : x0 + w]))
            continue
        img = np.ascontiguousarray(base[:h, :w])
        if kind == "creep":
            img = warp(img, np.full_like(u, -0.12 * i), np.zeros_like(v))
        elif kind == "breathe":
            a = 3.0 * np.sin(2 * np.pi * i / 20)
            img = warp(img, a * bump * (u - w / 2) / w * 2, a * bump * (v - h / 2) / h * 2)
        elif kind == "pull":
            img = warp(img, i * drag_x, i * drag_y)
        out.append(img)
    return out


def judge(frames: list[np.ndarray], fps: float = 25.0):
    return judge_motion(len(frames), lambda i: (frames[i], None), fps, MotionConfig())


def test_a_panning_view_is_a_moving_camera():
    m = judge(clip("pan"))
    assert m.camera == "moving"
    assert m.camera_move > 0.1  # 37 px in 25 frames of a 205-px diagonal
    assert "camera moving" in m.said


def test_a_still_view_over_breathing_tissue_is_a_still_camera_over_moving_tissue():
    m = judge(clip("breathe"))
    assert (m.camera, m.scene) == ("still", "moving")
    assert m.label == "camera still, tissue moving"
    assert m.moving_share is not None and m.moving_share > MotionConfig().deforming_share


def test_a_still_view_of_a_still_scene_is_still():
    m = judge(clip("still"))
    assert (m.camera, m.scene) == ("still", "rigid")
    assert m.moving_share == 0.0


def test_a_slowly_creeping_view_is_a_moving_camera_however_little_it_moved():
    """1.5% of the diagonal in a second, under the 2% the travel alone once needed: every
    corner moved, with one motion."""
    m = judge(clip("creep"))
    assert m.camera == "moving"
    assert m.camera_move is not None and m.camera_move < 0.02
    assert m.still_share is not None and m.still_share < 0.05
    assert m.identity_part is not None and m.identity_part < 0.1


def test_a_still_view_with_tissue_pulled_far_in_part_of_it_is_a_still_camera():
    """The failure the travel alone made (a da Vinci clip, camera fixed, tissue pulled hard in
    part of the view: 2.59% of the diagonal in a second, so a moving camera): most corners went
    far, but the left 40% of the view stayed put and no one motion moves both."""
    m = judge(clip("pull"))
    assert m.camera_move is not None and m.camera_move > 0.02  # the travel says "moving"
    assert (m.camera, m.scene) == ("still", "moving")
    assert m.still_share is not None and 0.2 <= m.still_share < 0.6
    assert m.identity_part is not None and m.identity_part > 0.5
    assert "camera still" in m.said and "stayed within" in m.said


def test_a_view_no_corner_lasts_through_is_a_moving_camera_whose_travel_is_unmeasured():
    """Each frame a new view (a fast pull-back through a cavity): no corner lasts a span, so
    its travel is unknown (None, not inf), said in words, and the judgement survives the
    poses summary's JSON."""
    rng = np.random.default_rng(0)
    noise = [rng.integers(0, 255, (96, 128), np.uint8) for _ in range(40)]
    frames = [cv2.GaussianBlur(f, (3, 3), 0) for f in noise]
    m = judge(frames)
    assert m.camera == "moving" and m.camera_move is None
    assert "too few corners lasted" in m.said and "inf" not in m.said
    assert FootageMotion.model_validate_json(m.model_dump_json()) == m


W, H = 320, 256
DIAG = float(np.hypot(W, H))


def corners(n: int = 300, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform((5, 5), (W - 5, H - 5), (n, 2))


def motion_of(start: np.ndarray, last: np.ndarray, seed: int = 0, spans: int = 5):
    """The judgement over `spans` spans of these corner motions, each with its own tracker noise
    (0.3 px) and a tenth of the corners lost."""
    cfg, rng = MotionConfig(), np.random.default_rng(seed)
    out = []
    for _ in range(spans):
        noisy = last + rng.normal(0.0, 0.3, last.shape)
        alive = rng.random(len(start)) > 0.1
        stray = np.linalg.norm(noisy - start, axis=1)
        out.append(span_motion(start, noisy, stray, alive, DIAG, cfg))
    return judge_spans(out, 25, 1.0, cfg)


def homography(start: np.ndarray, hm: np.ndarray) -> np.ndarray:
    return cv2.perspectiveTransform(start[None], hm)[0]


def test_one_global_motion_of_small_travel_is_a_moving_camera():
    """Turned 0.5 degrees about the centre, slid 6 px, a little perspective: the corners moved
    1.5% of the diagonal (under the 2% the travel alone needed), every one of them, as one."""
    start = corners()
    c, s = np.cos(np.radians(0.5)), np.sin(np.radians(0.5))
    about = np.array([[1, 0, W / 2], [0, 1, H / 2], [0, 0, 1.0]])
    turn = np.array([[c, -s, 6.0], [s, c, 1.0], [1e-5, 0, 1.0]])
    m = motion_of(start, homography(start, about @ turn @ np.linalg.inv(about)))
    assert m.camera == "moving" and m.scene == "not measured"
    assert m.camera_move is not None and 0.005 < m.camera_move < 0.02
    assert m.still_share is not None and m.still_share < MotionConfig().still_share
    assert m.homography_share is not None and m.homography_share > 0.9
    assert "camera moving" in m.said


def test_a_zoom_leaves_its_centre_put_but_one_homography_explains_all():
    """Coming closer (4% larger in a second): the corners near the centre of the zoom stay put,
    a fifth of them and more, yet standing still explains a fraction of what the zoom does."""
    start = corners()
    zoom = np.array([[1.04, 0, -0.04 * W / 2], [0, 1.04, -0.04 * H / 2], [0, 0, 1.0]])
    m = motion_of(start, homography(start, zoom))
    assert m.still_share is not None and m.still_share >= MotionConfig().still_share
    assert m.identity_part is not None and m.identity_part < 0.4
    assert m.camera == "moving"


def test_most_corners_fixed_while_a_region_moves_far_is_a_still_camera():
    """A still camera over tissue dragged in a third of the view: those corners moved 3-8% of
    the diagonal, unevenly; the rest stayed put."""
    start = corners()
    far = start[:, 0] > 0.65 * W
    pull = np.zeros_like(start)
    pull[far, 0] = (0.03 + 0.05 * (start[far, 1] / H)) * DIAG
    pull[far, 1] = -0.02 * DIAG * np.sin(np.pi * start[far, 0] / W)
    m = motion_of(start, start + pull)
    assert (m.camera, m.scene) == ("still", "moving")
    assert m.still_share is not None and 0.5 < m.still_share < 0.8
    assert m.identity_part is not None and m.identity_part > 0.8
    assert m.moving_share is not None and m.moving_share > 0.2


def test_a_dragged_majority_over_a_still_rest_is_still_though_the_median_corner_went_far():
    """The hard pull: 55% of the corners dragged 4-6% of the diagonal (the median corner too:
    the travel alone said "moving"), the other 45% put."""
    start = corners()
    far = start[:, 0] > 0.45 * W
    pull = np.zeros_like(start)
    pull[far, 0] = (0.04 + 0.02 * np.sin(np.pi * start[far, 1] / H)) * DIAG
    pull[far, 1] = 0.01 * DIAG * (start[far, 0] / W)
    m = motion_of(start, start + pull)
    assert m.camera_move is not None and m.camera_move > 0.02
    assert m.camera == "still"
    assert m.still_share is not None and 0.3 < m.still_share < 0.6


def test_spans_whose_view_changed_count_as_a_moving_camera():
    """Under min_kept of the corners lasted (a few fixed ones among them): nothing stayed put."""
    start = corners()
    cfg = MotionConfig()
    alive = np.zeros(len(start), bool)
    alive[:20] = True  # 7% lasted, all of them put
    span = span_motion(start, start.copy(), np.zeros(len(start)), alive, DIAG, cfg)
    assert span.still == 0.0 and not np.isfinite(span.travel)
    m = judge_spans([span] * 3, 25, 1.0, cfg)
    assert m.camera == "moving" and m.camera_move is None
    assert "the view changed" in m.said


def test_fps_from_the_frames_times():
    assert footage_fps([0.0, 0.04, 0.08, None], 10.0) == pytest.approx(25.0)
    assert footage_fps([None, None], 10.0) == 10.0


def video_frames(path: Path, n: int) -> list[np.ndarray]:
    cap = cv2.VideoCapture(str(path))
    out = []
    while len(out) < n:
        ok, frame = cap.read()
        if not ok:
            break
        scale = 320 / max(frame.shape[:2])
        small = cv2.resize(frame, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
        out.append(cv2.cvtColor(small, cv2.COLOR_BGR2GRAY))
    return out


def test_the_real_da_vinci_clip_is_a_still_camera_over_moving_tissue(shared_data: Path):
    """EndoNeRF's cutting clip (camera fixed, tissue pulled and cut in most of the view):
    measured 50% of the corners put, standing still 85% of what one homography explains
    (thresholds 20% and 50%); the median corner moved 0.81% of the diagonal in 1 s."""
    frames = video_frames(shared_data / "endonerf_cutting" / "cutting_gt.mp4", 156)
    m = judge(frames, 30.0)
    assert (m.camera, m.scene) == ("still", "moving")
    assert m.still_share is not None and m.still_share > 0.35
    assert m.identity_part is not None and m.identity_part > 0.7
    assert m.camera_move < 0.012


def test_the_real_moving_laparoscope_is_a_moving_camera(shared_data: Path):
    """endo.mp4 (a laparoscope panning over liver): measured no corner put (one homography
    explains 84%); the median corner moved 7.8% of the diagonal in 1 s."""
    frames = video_frames(shared_data / "laparoscopy_rvimlab" / "endo.mp4", 160)
    m = judge(frames, 25.0)
    assert m.camera == "moving"
    assert m.still_share is not None and m.still_share < 0.05
    assert m.identity_part is not None and m.identity_part < 0.1
    assert m.camera_move > 0.04
