"""Joint pose refinement: a learnt SE(3) correction per frame, as nerfstudio's camera optimizer
(SO3xR3) does it, because SfM poses of endoscopic footage are off by a little everywhere and the
field otherwise blurs to average the disagreement.

Convention (nerfstudio's, on rays): a correction (w, t) turns the camera about its own centre by
exp(w) in scene axes and moves it by t in scene units (one lumen radius):
c2w_refined = [exp(w) R | c + t] for c2w = [R | c]. Corrections start at 0 (the identity, so a
run with nothing learnt casts exactly the rays of the given poses), get their own optimiser group
with a small learning rate, wait for `start` and ramp up over `warmup` (the grid's upsampling
schedule is the coarse to fine: BARF's frequency annealing has no meaning for a grid), and are
held near 0 by a mild L2 penalty.

The gauge: moving every camera and the field together changes no image, and a straight tube
prior does not see a shift along its axis or a roll about it either, so the path would drift.
The training frames' corrections are taken relative to their mean (`gauge`): a rigid motion of
the whole path about its centroid is, to first order, the same (w, t) for every frame in these
axes, so the zero-mean corrections keep the given poses' frame and move the cameras only
relative to each other.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
from kornia.geometry.conversions import axis_angle_to_rotation_matrix
from scipy.spatial.transform import Rotation
from torch import nn

from endopipe.stages.nerf.scene import SceneBox
from endopipe.stages.nerf.view import RefinedCameras, RefinedFrame


def refinement_wanted(mode: str, source: str) -> bool:
    """auto: refine poses estimated by SfM, never ground truth or poses given in a file."""
    return mode == "on" or (mode == "auto" and source == "colmap")


def lr_factor(progress: float, start: float, warmup: float) -> float:
    """The corrections' learning-rate multiplier: 0 before `start`, then a linear ramp to 1."""
    if progress < start:
        return 0.0
    if warmup <= 0:
        return 1.0
    return min(1.0, (progress - start) / warmup)


class PoseCorrection(nn.Module):
    """Per-frame 6-vectors (axis-angle w, translation t), initialised at 0; the frames in
    `gauge` (the training frames) are corrected relative to their mean."""

    def __init__(self, n_frames: int, gauge: list[int] | None = None) -> None:
        super().__init__()
        self.delta = nn.Parameter(torch.zeros(max(n_frames, 1), 6))
        mask = torch.zeros(max(n_frames, 1))
        if gauge:
            mask[torch.as_tensor(gauge, dtype=torch.long)] = 1.0
        self.register_buffer("gauge", mask)

    def effective(self) -> torch.Tensor:
        """(F, 6) corrections as applied: the gauge frames' minus their mean."""
        g = self.gauge[:, None]
        if not bool(g.any()):
            return self.delta
        mean = (self.delta * g).sum(0) / g.sum()
        return self.delta - g * mean

    def apply(self, c2w: torch.Tensor) -> torch.Tensor:
        """Every frame's corrected pose (F, 4, 4): [exp(w) R | c + t]."""
        d = self.effective()
        top = torch.cat(
            [
                axis_angle_to_rotation_matrix(d[:, :3]) @ c2w[:, :3, :3],
                (c2w[:, :3, 3] + d[:, 3:])[..., None],
            ],
            -1,
        )
        return torch.cat([top, c2w[:, 3:, :]], 1)

    def penalty(self, frames: torch.Tensor) -> torch.Tensor:
        """Mean squared correction of `frames` (rotation in radians, translation in radii)."""
        return self.effective()[frames].square().sum(-1).mean()


def corrected_world(
    c2w_world: Sequence[np.ndarray], delta: np.ndarray, box: SceneBox
) -> list[np.ndarray]:
    """World poses with their corrections (F, 6; `PoseCorrection.effective`) in float64. The
    scene frame is the world turned by box.rotation (Q), shifted and divided by box.scale (s), so
    [exp(w) R_s | c_s + t] is, in the world, [Q exp(w) Q^T R | c + s Q t]: zero corrections give
    the poses back exactly."""
    q = np.asarray(box.rotation, np.float64)
    out = []
    for c, dv in zip(c2w_world, np.asarray(delta, np.float64), strict=True):
        c = np.asarray(c, np.float64)
        m = c.copy()
        if dv[:3].any():  # (Q Q^T is the identity only up to rounding)
            m[:3, :3] = q @ Rotation.from_rotvec(dv[:3]).as_matrix() @ q.T @ c[:3, :3]
        m[:3, 3] = c[:3, 3] + box.scale * q @ dv[3:]
        out.append(m)
    return out


def path_length(c2w: Sequence[np.ndarray]) -> float:
    """Length of the camera path: the summed distances between consecutive camera centres."""
    centres = np.array([np.asarray(c)[:3, 3] for c in c2w]).reshape(-1, 3)
    return float(np.linalg.norm(np.diff(centres, axis=0), axis=1).sum())


def movement(before: Sequence[np.ndarray], after: Sequence[np.ndarray], path: float) -> dict:
    """How far the cameras moved (world units, % of the camera path length, degrees): median
    and max over the frames."""
    b, a = np.asarray(before, np.float64), np.asarray(after, np.float64)
    if len(b) == 0:
        return {}
    dt = np.linalg.norm(a[:, :3, 3] - b[:, :3, 3], axis=1)
    rel = np.einsum("nji,njk->nik", b[:, :3, :3], a[:, :3, :3])  # R_before^T R_after
    deg = np.degrees(Rotation.from_matrix(rel).magnitude())
    pct = 100.0 * dt / path if path > 0 else np.full_like(dt, np.nan)
    return {
        "median_translation": float(np.median(dt)),
        "max_translation": float(dt.max()),
        "median_translation_pct": float(np.median(pct)),
        "max_translation_pct": float(pct.max()),
        "median_rotation_deg": float(np.median(deg)),
        "max_rotation_deg": float(deg.max()),
    }


def record(
    folder: Path,
    ids: list[int],
    heldout: list[int],
    given: Sequence[np.ndarray],
    refined: Sequence[np.ndarray],
    ran: bool,
    heldout_ran: bool,
) -> dict:
    """The summary's `pose_refine` block: whether refinement ran, how far the training frames'
    cameras moved (and, when they were fitted, the held-out ones'). When it ran, the refined
    poses go to cameras_refined.json (NerfView.c2w reads them)."""
    summary: dict = {"ran": ran}
    if not ran:
        return summary
    path = path_length(given)
    held = set(heldout)
    train = [k for k, i in enumerate(ids) if i not in held]
    summary.update(movement([given[k] for k in train], [refined[k] for k in train], path))
    summary["heldout_refined"] = heldout_ran
    if heldout_ran:
        h = [k for k, i in enumerate(ids) if i in held]
        summary["heldout"] = movement([given[k] for k in h], [refined[k] for k in h], path)
    frames = [
        RefinedFrame(index=i, c2w=np.asarray(c).tolist(), heldout=i in held)
        for i, c in zip(ids, refined, strict=True)
    ]
    RefinedCameras(frames=frames, movement=summary).write(folder)
    return summary
