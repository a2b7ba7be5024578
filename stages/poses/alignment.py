"""Poses moved into a frame with units: onto the ground truth by the sim3 that best maps
the camera centres (its world frame, its units), or into millimetres by a stereo rig's depth."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from endopipe.stages.camera import apply_sim3, umeyama
from endopipe.stages.ingest.view import IngestView
from endopipe.stages.poses.estimate import Estimate
from endopipe.stages.poses.motion import FootageMotion
from endopipe.stages.poses.stereo_scale import stereo_scale
from endopipe.stages.poses.summary import StereoScale
from endopipe.stages.poses.view import reconstruction_observations


def align_to(est: Estimate, gt_poses: dict[int, np.ndarray]) -> bool:
    """Move poses, points and the COLMAP model by the sim3 that maps camera centres onto GT."""
    common = sorted(set(est.c2w) & set(gt_poses))
    if len(common) < 3:
        return False
    src = np.array([est.c2w[i][:3, 3] for i in common])
    dst = np.array([gt_poses[i][:3, 3] for i in common])
    if np.linalg.norm(src - src.mean(0), axis=1).max() < 1e-12:
        return False
    s, R, t = umeyama(src, dst)
    transform(est, s, R, t)
    est.info["sim3_scale"] = float(s)
    return True


def scale_by_stereo(
    est: Estimate, ingest: IngestView, motion: FootageMotion | None, log: Callable[[str], None]
) -> tuple[StereoScale | None, str | None]:
    """Millimetres from the stereo depth: SfM poses scaled by it at their points; a still
    camera's one pose is its own frame, already in the stereo depth's millimetres. (None,
    None) when the points and the stereo depth share too few pixels."""
    if est.reconstruction is None:
        if motion is not None and motion.camera == "still":
            log(
                f"metric: a still camera, its depth measured by {ingest.stereo_measured_by}; "
                "its frame and depth are in millimetres"
            )
            return None, "stereo"
        log("metric scale: no SfM points to scale by the stereo depth; the poses stay unscaled")
        return None, None
    obs = reconstruction_observations(est.reconstruction, ingest.index_by_name(), set(est.c2w))
    if obs is not None:
        obs.resize((est.camera.width, est.camera.height), (ingest.width, ingest.height))
    scaled = stereo_scale(obs, est.c2w, ingest.stereo_depth, (ingest.height, ingest.width))
    if scaled is None:
        log("metric scale: too few SfM points have stereo depth; the poses stay unscaled")
        return None, None
    transform(est, scaled.mm_per_unit, np.eye(3), np.zeros(3))
    log(
        f"metric scale from stereo: {scaled.mm_per_unit:.4g} mm per SfM unit, from "
        f"{scaled.points} points (median deviation {100 * scaled.spread:.1f}%)"
    )
    return scaled, "stereo"


def transform(est: Estimate, s: float, R: np.ndarray, t: np.ndarray) -> None:
    """Move poses, points and the COLMAP model by the similarity x -> s R x + t."""
    est.c2w = {i: apply_sim3(s, R, t, c) for i, c in est.c2w.items()}
    if len(est.xyz):
        est.xyz = s * est.xyz @ R.T + t
    if est.reconstruction is not None:
        import pycolmap

        est.reconstruction.transform(pycolmap.Sim3d(s, pycolmap.Rotation3d(R), t))
