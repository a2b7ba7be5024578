"""A verdict on SfM poses without ground truth: each frame and the sequence, ok or doubtful,
with the reason in words.

Why: a wrong reconstruction looks fine in COLMAP's own numbers (the bench cavity from its video:
ATE 17.7% of the path at a mean reprojection error of 0.99 px). What gives it away is what no
single residual sees: the scale drifts (the scene's depth shrinks 50x along the path), the path
jumps, a frame holds on a handful of points, and two mappers that see the same matches disagree.
Thresholds: `VerdictConfig` (config.py); evidence: `FrameEvidence`, read from a Reconstruction.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import BaseModel
from scipy.ndimage import median_filter

from endopipe.stages.camera import rotation_angle_deg, umeyama
from endopipe.stages.poses.config import VerdictConfig
from endopipe.stages.poses.links import (
    WeakLink,
    cutting_links,
    link_strength,
    stretches,
    weak_links,
)
from endopipe.stages.poses.motion import FootageMotion

Status = Literal["ok", "doubtful", "not assessed"]


@dataclass
class FrameEvidence:
    """What a reconstruction says about each registered frame, in frame order (arrays of N)."""

    index: np.ndarray  # (N,) endopipe frame index
    c2w: np.ndarray  # (N, 4, 4)
    points: np.ndarray  # (N,) observations with a triangulated point
    reprojection_px: np.ndarray  # (N,) mean reprojection error of those (nan: none)
    median_depth: np.ndarray  # (N,) median camera-z of those points (nan: none)
    focal_px: float | None = None  # the shared camera's mean focal length (None: not known)
    link_points: np.ndarray | None = None  # (N-1,) points spanning each cut (links.py)
    link_share: np.ndarray | None = None  # (N-1,) their share of the points seen near it

    @property
    def centres(self) -> np.ndarray:
        return self.c2w[:, :3, 3]


def evidence_from_reconstruction(rec, index_of: dict[str, int]) -> FrameEvidence:
    """Per-frame evidence of a pycolmap Reconstruction; `index_of` maps image names to frames."""
    rows = []
    for image in rec.images.values():
        if not image.has_pose or image.name not in index_of:
            continue
        w2c = np.eye(4)
        w2c[:3] = image.cam_from_world().matrix()
        seen = [p for p in image.points2D if p.has_point3D()]
        ids = [p.point3D_id for p in seen]
        xy = np.array([p.xy for p in seen]).reshape(-1, 2)
        xyz = np.array([rec.points3D[i].xyz for i in ids]).reshape(-1, 3)
        z = xyz @ w2c[:3, :3].T + w2c[:3, 3]
        error = np.nan
        if len(ids):
            camera = rec.cameras[image.camera_id]
            proj = np.asarray(camera.img_from_cam(np.ascontiguousarray(z), False), np.float64)
            error = float(np.mean(np.linalg.norm(proj - xy, axis=1)))
        depth = float(np.median(z[:, 2])) if len(ids) else np.nan
        rows.append((index_of[image.name], np.linalg.inv(w2c), len(ids), error, depth, ids))
    rows.sort(key=lambda r: r[0])
    link_points, link_share = link_strength([np.array(r[5], dtype=np.int64) for r in rows])
    cameras = list(rec.cameras.values())
    return FrameEvidence(
        index=np.array([r[0] for r in rows], dtype=np.int64),
        c2w=np.array([r[1] for r in rows]).reshape(-1, 4, 4),
        points=np.array([r[2] for r in rows], dtype=np.int64),
        reprojection_px=np.array([r[3] for r in rows], dtype=np.float64),
        median_depth=np.array([r[4] for r in rows], dtype=np.float64),
        focal_px=float(cameras[0].mean_focal_length()) if len(cameras) == 1 else None,
        link_points=link_points,
        link_share=link_share,
    )


SOUND = "sound on its own"  # how `others` notes a mapper not kept that was judged sound


class FrameVerdict(BaseModel):
    index: int
    status: Literal["ok", "doubtful", "unregistered"]
    reasons: list[str] = []
    points: int = 0
    reprojection_px: float | None = None
    disagreement_pct: float | None = None  # distance to the other mapper's camera, % of path


class PoseVerdict(BaseModel):
    """02_poses/verdict.json: the sequence's and each frame's verdict, and the evidence."""

    status: Status
    reasons: list[str] = []
    mapper: str = ""
    depth_drift: float | None = None
    disagreement_pct: float | None = None  # the two mappers' RMS difference, % of path
    others: dict[str, str] = {}  # mapper not kept -> why
    frames: list[FrameVerdict] = []
    weak_links: list[WeakLink] = []  # cuts few points span (links.py), in frame order
    motion: FootageMotion | None = None  # the footage's motion, judged before SfM (motion.py)

    def doubtful(self) -> list[FrameVerdict]:
        """Registered frames called doubtful (unregistered ones are not: they have no pose)."""
        return [f for f in self.frames if f.status == "doubtful"]

    def doubtful_frames(self) -> list[int]:
        return [f.index for f in self.doubtful()]

    def sound_others(self) -> list[str]:
        """Mappers not kept whose reconstruction was sound on its own: the user's alternative."""
        return [m for m, why in self.others.items() if why.startswith(SOUND)]

    def write(self, path: Path) -> None:
        path.write_text(self.model_dump_json(indent=2))


def judge(
    ev: FrameEvidence,
    n_frames: int,
    cfg: VerdictConfig,
    mapper: str = "",
    other: FrameEvidence | None = None,
) -> PoseVerdict:
    """The verdict on one reconstruction; with `other` (another mapper's on the same matches)
    their disagreement counts too."""
    frames = {i: FrameVerdict(index=i, status="unregistered") for i in range(n_frames)}
    seq: list[str] = []
    for k, i in enumerate(ev.index):
        f = frames[int(i)]
        f.status, f.points = "ok", int(ev.points[k])
        if np.isfinite(ev.reprojection_px[k]):
            f.reprojection_px = round(float(ev.reprojection_px[k]), 3)
        if f.points < cfg.min_frame_points:
            f.reasons.append(f"sees {f.points} triangulated points (< {cfg.min_frame_points})")
        if f.reprojection_px is not None and f.reprojection_px > cfg.max_frame_reprojection_px:
            f.reasons.append(
                f"reprojection error {f.reprojection_px:.2f} px (> {cfg.max_frame_reprojection_px})"
            )
    for k, why in jumps(ev, cfg):
        for i in (ev.index[k], ev.index[k + 1]):
            frames[int(i)].reasons.append(why)
    links = []
    if ev.link_points is not None and ev.link_share is not None:
        links = weak_links(ev.index, ev.link_points, ev.link_share, cfg.min_link_share)
    if links:
        seq.append(loose_stretches(ev, links, frames, cfg.min_link_share))
    drift = depth_drift(ev.median_depth)
    if drift is not None and drift > cfg.max_depth_drift:
        seq.append(
            f"scale drift: the scene's depth changes {drift:.1f}x along the path "
            f"(> {cfg.max_depth_drift:g}x)"
        )
    disagreement = None
    if other is not None:
        disagreement, per_frame = compare_paths(ev, other)
        if disagreement is not None:
            for i, d in per_frame.items():
                frames[i].disagreement_pct = round(d, 2)
                if d > cfg.max_disagreement_pct:
                    frames[i].reasons.append(f"{d:.1f}% of the path from the other mapper's camera")
            if disagreement > cfg.max_disagreement_pct:
                seq.append(
                    f"the two mappers disagree by {disagreement:.1f}% of the path "
                    f"(> {cfg.max_disagreement_pct:g}%)"
                )
    for f in frames.values():
        if f.reasons and f.status == "ok":
            f.status = "doubtful"
    registered = len(ev.index) / max(n_frames, 1)
    if registered < cfg.min_registered:
        seq.append(
            f"only {len(ev.index)} of {n_frames} frames registered (< {cfg.min_registered:.0%})"
        )
    doubtful = sum(f.status == "doubtful" for f in frames.values())
    if doubtful > cfg.max_doubtful_frames * max(len(ev.index), 1):
        seq.append(
            f"{doubtful} of {len(ev.index)} registered frames doubtful "
            f"(> {cfg.max_doubtful_frames:.0%})"
        )
    return PoseVerdict(
        status="doubtful" if seq else "ok",
        reasons=seq,
        mapper=mapper,
        depth_drift=None if drift is None else round(drift, 3),
        disagreement_pct=None if disagreement is None else round(disagreement, 3),
        frames=list(frames.values()),
        weak_links=links,
    )


def loose_stretches(
    ev: FrameEvidence, links: list[WeakLink], frames: dict[int, FrameVerdict], min_share: float
) -> str:
    """Every stretch but the longest, between weak links, is doubtful (its frames say by how
    few points it hangs on); the sequence's reason, in words."""
    parts = stretches(ev.index, cutting_links(ev.index, links))
    longest = max(parts, key=len)
    for part in parts:
        if part is longest:
            continue
        bounding = [w for w in links if w.before == part[0] or w.after == part[-1]]
        link = min(bounding, key=lambda w: w.share)
        for i in part:
            frames[i].reasons.append(
                f"in frames {part[0]}-{part[-1]}, held to the rest by {link.points} points"
            )
    cuts = ", ".join(
        f"{link.points} points ({link.share:.0%} of those seen near) between frames "
        f"{link.after} and {link.before}"
        for link in links
    )
    return (
        f"the model hangs together by few points: {cuts} (< {min_share:.0%}); its "
        f"{len(parts)} stretches may be placed wrong against each other"
    )


def jumps(ev: FrameEvidence, cfg: VerdictConfig) -> list[tuple[int, str]]:
    """Steps between consecutive registered frames far longer than the median step: (k, why)
    for the step from ev.index[k] to ev.index[k + 1]."""
    if len(ev.index) < 4:
        return []
    gap = np.diff(ev.index).astype(np.float64)  # unregistered frames in between: a longer step
    move = np.linalg.norm(np.diff(ev.centres, axis=0), axis=1) / gap
    rel = [a[:3, :3].T @ b[:3, :3] for a, b in zip(ev.c2w[:-1], ev.c2w[1:], strict=True)]
    turn = np.array([rotation_angle_deg(r) for r in rel]) / gap
    out = []
    for k in range(len(move)):
        if move[k] > cfg.max_jump * max(np.median(move), 1e-12):
            out.append((k, f"jumps {move[k] / np.median(move):.1f}x the median move"))
        elif turn[k] > max(cfg.max_jump * np.median(turn), cfg.min_jump_deg):
            out.append((k, f"turns {turn[k]:.1f} deg in one step ({np.median(turn):.2f} median)"))
    return out


def depth_drift(median_depth: np.ndarray, window: int = 5) -> float | None:
    """How many times the frames' typical scene depth changes along the path (running median,
    so one odd frame does not count): a scale drift shrinks the whole scene with the steps."""
    d = median_depth[np.isfinite(median_depth) & (median_depth > 0)]
    if len(d) < window:
        return None
    smooth = median_filter(d, size=window, mode="nearest")
    return float(smooth.max() / smooth.min())


def compare_paths(a: FrameEvidence, b: FrameEvidence) -> tuple[float | None, dict[int, float]]:
    """RMS and per-frame distance between two mappers' camera centres after the similarity that
    maps b onto a, as % of a's path length (frames both registered)."""
    common = sorted(set(a.index.tolist()) & set(b.index.tolist()))
    if len(common) < 3:
        return None, {}
    pa = a.centres[np.searchsorted(a.index, common)]
    pb = b.centres[np.searchsorted(b.index, common)]
    length = float(np.linalg.norm(np.diff(pa, axis=0), axis=1).sum())
    if length <= 0 or np.ptp(pb, axis=0).max() <= 0:
        return None, {}
    s, R, t = umeyama(pb, pa)
    dist = np.linalg.norm(s * pb @ R.T + t - pa, axis=1) * 100.0 / length
    per_frame = {int(i): float(d) for i, d in zip(common, dist, strict=True)}
    return float(np.sqrt(np.mean(dist**2))), per_frame


def pick_mapper(
    evidence: dict[str, FrameEvidence | None],
    n_frames: int,
    cfg: VerdictConfig,
    failures: dict[str, str] | None = None,
) -> PoseVerdict:
    """Keep the soundest of several mappers' reconstructions of the same matches.

    Each is judged on its own; the one with the fewest sequence-level reasons wins, then the one
    registering more frames, then the first named. The winner is judged again against a runner-up
    that looked sound on its own: two sound mappers that disagree leave the poses doubtful,
    while a runner-up that is itself doubtful explains the disagreement and is only noted.
    """
    failures = dict(failures or {})
    alone = {m: judge(ev, n_frames, cfg, m) for m, ev in evidence.items() if ev is not None}
    if not alone:
        raise ValueError("no mapper gave a model")
    order = list(evidence)
    ranked = sorted(
        alone,
        key=lambda m: (len(alone[m].reasons), -len(evidence[m].index), order.index(m)),  # type: ignore[union-attr]
    )
    kept = ranked[0]
    sound = [m for m in ranked[1:] if alone[m].status == "ok"]
    other = evidence[sound[0]] if sound else None
    verdict = judge(evidence[kept], n_frames, cfg, kept, other=other)  # type: ignore[arg-type]
    for m in ranked[1:]:
        gap, _ = compare_paths(evidence[kept], evidence[m])  # type: ignore[arg-type]
        apart = "" if gap is None else f"; {gap:.1f}% of the path from the kept poses"
        lenses = lens_disagreement(evidence[kept], evidence[m], cfg)  # type: ignore[arg-type]
        if alone[m].status == "ok" and lenses is not None:
            verdict.others[m] = f"another lens ({lenses}), sound otherwise{apart}"
            verdict.reasons.append(
                f"the two mappers' lenses disagree ({lenses}): the footage does not fix the "
                "lens; --intrinsics FILE gives it"
            )
            verdict.status = "doubtful"
        elif alone[m].status == "ok":
            verdict.others[m] = f"{SOUND}{apart}"
        else:
            verdict.others[m] = f"doubtful: {'; '.join(alone[m].reasons)}{apart}"
        if verdict.disagreement_pct is None and gap is not None:
            verdict.disagreement_pct = round(gap, 3)
    for m, why in failures.items():
        verdict.others[m] = f"no model: {why}"
    return verdict


def lens_disagreement(kept: FrameEvidence, other: FrameEvidence, cfg: VerdictConfig) -> str | None:
    """How two mappers' self-calibrated focal lengths differ, in words, when their ratio is
    over `max_focal_ratio`; else None. Why: on C3VD the incremental mapper, sound by every
    other test, settled at 413 px against the global mapper's 156 (25 against 46 degrees at
    half the frame height; the scope's calibration says 45), and its depth ranked pixels worse
    than the radial guess. Paths can agree while lenses do not."""
    a, b = kept.focal_px, other.focal_px
    if a is None or b is None or min(a, b) <= 0 or max(a, b) / min(a, b) <= cfg.max_focal_ratio:
        return None
    return f"f {a:.0f} px kept against {b:.0f} px, {max(a, b) / min(a, b):.2f}x"


def ranges(indices: list[int]) -> str:
    """[0, 1, 2, 7, 9, 10] -> '0-2, 7, 9-10'."""
    parts: list[str] = []
    start = prev = None
    for i in [*indices, None]:
        if i is not None and prev is not None and i == prev + 1:
            prev = i
            continue
        if start is not None:
            parts.append(f"{start}" if start == prev else f"{start}-{prev}")
        start = prev = i
    return ", ".join(parts)
