"""The footage's motion, judged before SfM: a still camera over moving tissue is told from a
moving camera, on frames made here (known motion) and on the real clips (known to be still or
moving from their provenance)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from endopipe.stages.poses.config import MotionConfig
from endopipe.stages.poses.motion import FootageMotion, footage_fps, judge_motion


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
    """`pan`: the view slides 1.5 px a frame (a moving camera); `breathe`: a still view whose
    middle swells and settles (up to 3 px, period 20 frames); `still`: nothing moves."""
    base = texture(h + 8, w + 80)
    v, u = np.mgrid[0:h, 0:w].astype(np.float32)
    bump = np.exp(-(((u - w / 2) / (w / 4)) ** 2 + ((v - h / 2) / (h / 4)) ** 2))
    out = []
    for i in range(n):
        if kind == "pan":
            x0 = int(round(1.5 * i))
            out.append(np.ascontiguousarray(base[:h, x0 : x0 + w]))
            continue
        img = np.ascontiguousarray(base[:h, :w])
        if kind == "breathe":
            a = 3.0 * np.sin(2 * np.pi * i / 20)
            img = warp(img, a * bump * (u - w / 2) / w * 2, a * bump * (v - h / 2) / h * 2)
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
    """EndoNeRF's cutting clip (camera fixed, tissue pulled and cut): measured 0.71% of the
    diagonal in 1 s, 83% of the corners moving; the threshold is 2%."""
    frames = video_frames(shared_data / "endonerf_cutting" / "cutting_gt.mp4", 156)
    m = judge(frames, 30.0)
    assert (m.camera, m.scene) == ("still", "moving")
    assert m.camera_move < 0.012


def test_the_real_moving_laparoscope_is_a_moving_camera(shared_data: Path):
    """endo.mp4 (a laparoscope panning over liver): measured 7.3% of the diagonal in 1 s."""
    frames = video_frames(shared_data / "laparoscopy_rvimlab" / "endo.mp4", 160)
    m = judge(frames, 25.0)
    assert m.camera == "moving"
    assert m.camera_move > 0.04
