"""One trajectory from the windows' reconstructions.

Each window has its own frame and scale (COLMAP's). Neighbouring windows share keyframes; the
similarity that maps one onto the other is fitted on those shared cameras: its rotation from
their orientations (the camera centres of a short stretch of colon lie nearly on a line, which
leaves a rotation about that line undetermined), scale and shift from their centres. Windows
are chained from the first; where a junction cannot be fitted (a failed window, too few shared
cameras) or fits badly, the chain breaks and the next window starts a new segment: a bad window
is reported, never bent into the trajectory.
"""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel, Field

from endopipe.stages.camera.transforms import apply_sim3
from endopipe.stages.metrics.depth import path_length

#: A junction whose shared cameras sit further apart than this, after the fit (RMS, % of the
#: shared stretch's path), breaks the chain.
MAX_JUNCTION_PCT = 10.0
MIN_SHARED = 3


class Sim3(BaseModel):
    """x -> s R x + t."""

    s: float = 1.0
    R: list[list[float]] = Field(default_factory=lambda: np.eye(3).tolist())
    t: list[float] = Field(default_factory=lambda: [0.0, 0.0, 0.0])

    def then(self, outer: Sim3) -> Sim3:
        """outer after self."""
        r1, r2 = np.array(outer.R), np.array(self.R)
        t = outer.s * r1 @ np.array(self.t) + np.array(outer.t)
        return Sim3(s=outer.s * self.s, R=(r1 @ r2).tolist(), t=t.tolist())

    def pose(self, c2w: np.ndarray) -> np.ndarray:
        return apply_sim3(self.s, np.array(self.R), np.array(self.t), c2w)


class Junction(BaseModel):
    """Where window `b` was joined to window `a` (or why not)."""

    a: str
    b: str
    shared: int = Field(description="Keyframes registered in both.")
    error_pct: float | None = Field(
        None, description="RMS distance of the shared cameras after the fit, % of their path."
    )
    scale: float | None = Field(None, description="b's units in a's.")
    joined: bool
    reason: str = ""


class JoinedFrame(BaseModel):
    source_index: int
    window: str
    segment: int
    c2w: list[list[float]]


class ScaleKnot(BaseModel):
    """A keyframe where the segment's path was redrawn for scale drift (light_scale.py)."""

    source_index: int
    segment: int
    factor: float = Field(description="Lengths here are multiplied by this.")
    centre: list[float] = Field(description="The keyframe's centre as joined.")
    redrawn: list[float] = Field(description="Its centre on the redrawn path.")


class Joined(BaseModel):
    """The joined trajectory (recording/trajectory.json)."""

    frames: list[JoinedFrame]
    junctions: list[Junction]
    segments: int
    windows: dict[str, Sim3] = Field(description="Each placed window's map into its segment.")
    segment_of: dict[str, int] = Field(default_factory=dict, description="Each placed window's.")
    knots: list[ScaleKnot] = Field(
        default_factory=list, description="Where the path was redrawn (empty: as joined)."
    )

    def place(self, window: str, source_index: int, c2w: np.ndarray) -> np.ndarray:
        """A camera of `window` (its own frame and units) in its segment's: the window's
        similarity, then the redrawn path where the camera is."""
        return self.redraw(
            self.segment_of.get(window, -1), source_index, self.windows[window].pose(c2w)
        )

    def redraw(self, segment: int, source_index: int, pose: np.ndarray) -> np.ndarray:
        """A camera of the segment as joined, on the redrawn path: its offset from the nearest
        keyframe before it scaled as the path is there."""
        found = self._redrawn_at(segment, source_index)
        if found is None:
            return pose
        anchor, factor = found
        pose = pose.copy()
        pose[:3, 3] = np.array(anchor.redrawn) + factor * (pose[:3, 3] - np.array(anchor.centre))
        return pose

    def depth_scale(self, window: str, source_index: int) -> float:
        """What a depth map of `window` at this frame is multiplied by in its segment."""
        found = self._redrawn_at(self.segment_of.get(window, -1), source_index)
        return self.windows[window].s * (1.0 if found is None else found[1])

    def _redrawn_at(self, segment: int, source_index: int) -> tuple[ScaleKnot, float] | None:
        """The segment's knot at or before the frame (else its first) and the length factor
        there (interpolated between knots); None where the segment was not redrawn."""
        knots = [k for k in self.knots if k.segment == segment]
        if not knots:
            return None
        at = [k.source_index for k in knots]
        anchor = knots[max(int(np.searchsorted(at, source_index, side="right")) - 1, 0)]
        return anchor, float(np.interp(source_index, at, [k.factor for k in knots]))


def fit_similarity(a: list[np.ndarray], b: list[np.ndarray]) -> Sim3:
    """The similarity taking cameras `b` (c2w) onto the same cameras `a`: rotation from the
    orientations (chordal mean), then scale and shift from the centres."""
    m = sum(ra[:3, :3] @ rb[:3, :3].T for ra, rb in zip(a, b, strict=True))
    u, _, vt = np.linalg.svd(m)
    r = u @ np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))]) @ vt
    ca = np.array([p[:3, 3] for p in a])
    cb = np.array([p[:3, 3] for p in b]) @ r.T
    xa, xb = ca - ca.mean(0), cb - cb.mean(0)
    s = float((xa * xb).sum() / max((xb * xb).sum(), 1e-12))
    t = ca.mean(0) - s * cb.mean(0)
    return Sim3(s=s, R=r.tolist(), t=t.tolist())


def junction_error_pct(a: list[np.ndarray], b: list[np.ndarray], sim: Sim3) -> float:
    ca = np.array([p[:3, 3] for p in a])
    cb = np.array([sim.pose(p)[:3, 3] for p in b])
    rms = float(np.sqrt(np.mean(np.sum((ca - cb) ** 2, axis=1))))
    return 100.0 * rms / max(path_length(ca), 1e-12)


def join_windows(
    names: list[str],
    poses: list[dict[int, np.ndarray] | None],
    frames: list[list[int]],
    breaks: dict[int, str] | None = None,
) -> Joined:
    """Chain the windows (in recording order): `poses[k]` maps a source_index to window k's
    c2w (None: the window failed), `frames[k]` is window k's keyframes, `breaks` the windows
    that start a new stretch and why (never joined to the window before). Each keyframe takes
    its pose from the window in which it sits nearest the middle."""
    breaks = breaks or {}
    placed: dict[str, tuple[int, Sim3]] = {}
    junctions: list[Junction] = []
    segment = -1
    for k, name in enumerate(names):
        prev = names[k - 1] if k else None
        if poses[k] is None or len(poses[k]) < MIN_SHARED:
            if prev is not None:
                junctions.append(
                    Junction(a=prev, b=name, shared=0, joined=False, reason=f"{name} failed")
                )
            continue
        if k in breaks:
            junctions.append(Junction(a=prev, b=name, shared=0, joined=False, reason=breaks[k]))
            segment += 1
            placed[name] = (segment, Sim3())
            continue
        if prev is None or prev not in placed:
            if prev is not None:
                junctions.append(
                    Junction(a=prev, b=name, shared=0, joined=False, reason=f"{prev} failed")
                )
            segment += 1
            placed[name] = (segment, Sim3())
            continue
        shared = sorted(set(poses[k - 1]) & set(poses[k]))
        if len(shared) < MIN_SHARED:
            junctions.append(
                Junction(a=prev, b=name, shared=len(shared), joined=False, reason="too few shared")
            )
            segment += 1
            placed[name] = (segment, Sim3())
            continue
        a = [poses[k - 1][i] for i in shared]
        b = [poses[k][i] for i in shared]
        sim = fit_similarity(a, b)
        err = junction_error_pct(a, b, sim)
        ok = err <= MAX_JUNCTION_PCT
        junctions.append(
            Junction(
                a=prev,
                b=name,
                shared=len(shared),
                error_pct=err,
                scale=sim.s,
                joined=ok,
                reason="" if ok else f"shared cameras {err:.1f}% apart after the fit",
            )
        )
        if ok:
            seg, outer = placed[prev]
            placed[name] = (seg, sim.then(outer))
        else:
            segment += 1
            placed[name] = (segment, Sim3())
    joined: list[JoinedFrame] = []
    everything = sorted({i for w in frames for i in w})
    for i in everything:
        best = None
        for k, name in enumerate(names):
            if name not in placed or poses[k] is None or i not in poses[k]:
                continue
            off_middle = abs(frames[k].index(i) - (len(frames[k]) - 1) / 2)
            if best is None or off_middle < best[0]:
                best = (off_middle, k)
        if best is None:
            continue  # registered in no placed window: no pose (never made up)
        k = best[1]
        seg, sim = placed[names[k]]
        c2w = sim.pose(poses[k][i])
        joined.append(JoinedFrame(source_index=i, window=names[k], segment=seg, c2w=c2w.tolist()))
    return Joined(
        frames=joined,
        junctions=junctions,
        segments=segment + 1,
        windows={n: s for n, (_, s) in placed.items()},
        segment_of={n: seg for n, (seg, _) in placed.items()},
    )
