"""A pose and a depth map for every frame of a recording, not only its keyframes.

A frame that is not a posed keyframe is registered against the windows that posed the keyframes
around it: corners of each neighbouring keyframe that the window's depth map places in 3D are
tracked into the frame (Lucas-Kanade, forward-backward checked), and its pose is the PnP fit of
those 2D-3D matches (OpenCV, RANSAC, started at the keyframe's pose). The window of the keyframe
before is tried first, then the one after (a frame between two segments is placed in whichever
it registers to). Its depth is then rendered from that window's field, as the depth stage
renders a keyframe's. A frame that does not register gets no pose and no depth, unknown and
never interpolated, and `frames.json` says why (with ingest's own reason for not keeping it).

Frames stream from the input once, in order; the baked fields of two windows are held at a time.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from pydantic import BaseModel
from rich.console import Console

from endopipe.pipeline.errors import InputError
from endopipe.pipeline.runner import Pipeline
from endopipe.pipeline.stage import CaseInfo, StageConfig, write_json
from endopipe.recording.join import Joined
from endopipe.recording.paths import DEPTH_DIR, FRAMES_FILE
from endopipe.recording.summary import RecordingSummary
from endopipe.stages.camera import Camera, pixel_directions
from endopipe.stages.ingest.keyframes import track_corners

MIN_INLIERS = 30
#: Corners taken from each keyframe, and their quality relative to the strongest one. A specular
#: highlight is the strongest corner of most endoscopic frames: at OpenCV's customary 0.01 it left
#: 25-66 trackable corners on the tissue of a real sinus recording's keyframes, and 54 of its
#: frames unregistered; at 0.001 all 54 register with 64-860 inliers.
CORNERS, CORNER_QUALITY = 1000, 0.001


class FramePose(BaseModel):
    """recording/frames.json: one line per frame ingest judged (its stride, start and end)."""

    source_index: int
    window: str | None  # the window it was posed in (or last tried)
    kind: str  # keyframe | registered | unregistered
    segment: int | None = None  # the segment whose frame and units c2w is in
    inliers: int | None = None
    reason: str | None = None  # unregistered: why
    dropped: str | None = None  # not a keyframe: ingest's reason (little_motion, blurred, ...)
    doubt: str | None = None  # a keyframe its neighbours place elsewhere (second_opinion)
    c2w: list[list[float]] | None = None  # its segment's frame and units


class FramesFile(BaseModel):
    """recording/frames.json: every frame ingest judged."""

    frames: list[FramePose]


@dataclass
class Reference:
    """A keyframe as seen by its window: grey image, depth (window units), pose (window frame)."""

    grey: np.ndarray
    depth: np.ndarray
    c2w: np.ndarray


class WindowSight:
    """One window's keyframes, camera and field, loaded when a frame first needs them."""

    def __init__(self, pipe: Pipeline, folder: Path, depth_cfg: Any) -> None:
        from endopipe.stages.depth.renderer import FieldSight
        from endopipe.stages.mesh.inputs import valid_depth

        self.ingest = pipe.view(folder, "ingest")
        self.depth_view = pipe.view(folder, "depth")
        views = [pipe.view(folder, s) for s in ("poses", "centerline", "nerf")]
        sight = FieldSight.open(depth_cfg, self.ingest, *views)
        self.camera: Camera = sight.camera
        self.c2w = sight.c2w
        self.render = sight.render
        self.index = {f.source_index: f.index for f in self.ingest.frames}
        self._valid_depth = valid_depth

    def reference(self, source_index: int) -> Reference | None:
        i = self.index.get(source_index)
        if i is None or i not in self.c2w or not self.depth_view.has_depth(i):
            return None
        grey = cv2.cvtColor(self.ingest.image(i), cv2.COLOR_RGB2GRAY)
        return Reference(grey, self._valid_depth(self.depth_view, i, 0.5), self.c2w[i])


def register(
    grey: np.ndarray, refs: list[Reference], camera: Camera
) -> tuple[np.ndarray | None, int, str]:
    """The frame's c2w in the references' frame (None: it does not register), the inliers, and
    why not (empty when it registers)."""
    obj, img = [], []
    tracked = 0
    for ref in refs:
        usable = ((ref.depth > 0) * 255).astype(np.uint8)
        corners = cv2.goodFeaturesToTrack(ref.grey, CORNERS, CORNER_QUALITY, 3, mask=usable)
        if corners is None:
            continue
        found, ok = track_corners(ref.grey, grey, corners.astype(np.float32), 1.0)
        tracked += int(ok.sum())
        if not ok.any():
            continue
        uv = corners.reshape(-1, 2)[ok]
        z = ref.depth[uv[:, 1].round().astype(int), uv[:, 0].round().astype(int)]
        keep = z > 0
        d = pixel_directions(camera, uv[keep, 0], uv[keep, 1]) * z[keep, None]
        obj.append(d @ ref.c2w[:3, :3].T + ref.c2w[:3, 3])
        seen = found.reshape(-1, 2)[ok][keep]
        img.append(pixel_directions(camera, seen[:, 0], seen[:, 1])[:, :2])
    matches = sum(len(o) for o in obj)
    if matches < MIN_INLIERS:
        return None, 0, f"{tracked} corners tracked from the keyframes (< {MIN_INLIERS})"
    obj_pts, img_pts = np.concatenate(obj), np.concatenate(img)
    w2c = np.linalg.inv(refs[0].c2w)
    rvec, _ = cv2.Rodrigues(w2c[:3, :3])
    tvec = w2c[:3, 3].reshape(3, 1).copy()
    ok, rvec, tvec, inliers = cv2.solvePnPRansac(
        obj_pts,
        img_pts,
        np.eye(3),
        None,
        rvec,
        tvec,
        useExtrinsicGuess=True,
        reprojectionError=1.5 / camera.fx,
        iterationsCount=200,
    )
    if not ok or inliers is None or len(inliers) < MIN_INLIERS:
        kept = 0 if inliers is None else len(inliers)
        return (
            None,
            kept,
            f"one rigid pose fits {kept} of {matches} tracked corners (< {MIN_INLIERS})",
        )
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = cv2.Rodrigues(rvec)[0], tvec.reshape(3)
    return np.linalg.inv(out), len(inliers), ""


class Sights:
    """The windows' sights, the last `keep` used held in memory (a baked field each)."""

    def __init__(self, pipe: Pipeline, windows_dir: Path, depth_cfg: Any, keep: int = 2) -> None:
        self.pipe, self.windows_dir, self.depth_cfg, self.keep = pipe, windows_dir, depth_cfg, keep
        self._held: dict[str, WindowSight] = {}

    def __getitem__(self, name: str) -> WindowSight:
        sight = self._held.pop(name, None)
        if sight is None:
            sight = WindowSight(self.pipe, self.windows_dir / name, self.depth_cfg)
        self._held[name] = sight  # most recent last
        while len(self._held) > self.keep:
            self._held.pop(next(iter(self._held)))
        return sight


def attempts(source_index: int, order: list[int], keys: dict) -> list[tuple[str, list[int]]]:
    """The windows a frame that is no posed keyframe is registered against, in the order tried,
    each with the keyframes whose corners are tracked: the keyframes around it, in the window
    of the one before, then of the one after (different windows near a junction, different
    segments across a break)."""
    at = int(np.searchsorted(order, source_index))
    around = [order[k] for k in (at - 1, at) if 0 <= k < len(order)]
    out: list[tuple[str, list[int]]] = []
    for k in around:
        window = keys[k].window
        if all(window != w for w, _ in out):
            same = [j for j in around if keys[j].segment == keys[k].segment]
            out.append((window, same))
    return out


#: A keyframe is doubtful when its registration from a neighbouring keyframe lies further than
#: this share of the step between them from its SfM pose, and turned more than this many degrees.
#: On a real sinus recording sound keyframes agreed within 0.22 of the step and 0.7 degrees; two
#: the mapper placed wrong (10-21% of the path off) lay 0.85-0.92 of the step and 6-16 degrees off.
SECOND_OPINION_STEP, SECOND_OPINION_DEG = 0.5, 3.0


def second_opinion(
    grey: np.ndarray, source_index: int, c2w: np.ndarray, sight: WindowSight, order: list[int]
) -> str | None:
    """Why a keyframe's SfM pose is doubtful, or None: it is registered as any other frame from
    the keyframe before it (else the one after) in its window, on that keyframe's depth, and
    the two poses compared. None also when it does not register from either (no evidence)."""
    from endopipe.stages.camera import rotation_angle_deg

    k = order.index(source_index)
    for n in (order[m] for m in (k - 1, k + 1) if 0 <= m < len(order)):
        ref = sight.reference(n)
        if ref is None:
            continue
        again, _, _ = register(grey, [ref], sight.camera)
        if again is None:
            continue
        step = float(np.linalg.norm(ref.c2w[:3, 3] - c2w[:3, 3]))
        off = float(np.linalg.norm(again[:3, 3] - c2w[:3, 3])) / max(step, 1e-12)
        turn = rotation_angle_deg(again[:3, :3].T @ c2w[:3, :3])
        if off > SECOND_OPINION_STEP and turn > SECOND_OPINION_DEG:
            return (
                f"registered from keyframe {n}, it lies {off:.2f} of the step and "
                f"{turn:.1f} deg from its SfM pose"
            )
        return None
    return None


def every_frame(
    pipe: Pipeline,
    frames_in: Iterator[tuple[int, np.ndarray]],
    windows_dir: Path,
    joined: Joined,
    depth_cfg: Any,
    write_depth: Callable[[int, np.ndarray, np.ndarray], None],
    progress: Callable[[], None] = lambda: None,
    dropped: dict[int, str] | None = None,
) -> list[FramePose]:
    """Pose (and, through `write_depth(source_index, depth, rgb)`, the depth map in its
    segment's units) of every frame from `frames_in` ((source_index, RGB at the working
    size)); `dropped`: why ingest kept a frame as no keyframe."""
    keys = {f.source_index: f for f in joined.frames}
    order = sorted(keys)
    dropped = dropped or {}
    if not order:
        return []
    sights = Sights(pipe, windows_dir, depth_cfg)
    out: list[FramePose] = []
    for source_index, rgb in frames_in:
        progress()
        line = FramePose(
            source_index=source_index,
            window=None,
            kind="unregistered",
            dropped=dropped.get(source_index),
        )
        out.append(line)
        c2w = None
        grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
        if source_index in keys:
            line.window, line.kind = keys[source_index].window, "keyframe"
            sight = sights[line.window]
            c2w = sight.c2w[sight.index[source_index]]
            line.doubt = second_opinion(grey, source_index, c2w, sight, order)
        else:
            why = []
            for name, around in attempts(source_index, order, keys):
                sight = sights[name]
                line.window = name
                refs = [r for k in around if (r := sight.reference(k)) is not None]
                if not refs:
                    why.append(f"{name}: no depth at keyframes {around}")
                    continue
                c2w, line.inliers, reason = register(grey, refs, sight.camera)
                if c2w is not None:
                    line.kind = "registered"
                    break
                why.append(f"{name}: {reason}")
            line.reason = "; ".join(why) if c2w is None else None
        if c2w is None:
            continue
        depth = sight.render(sight.camera, c2w, None, colour=False)["depth"]
        scale = np.float32(joined.depth_scale(line.window, source_index))
        write_depth(source_index, (depth * scale).astype(np.float32), rgb)
        line.segment = joined.segment_of.get(line.window)
        line.c2w = joined.place(line.window, source_index, c2w).tolist()
    return out


#: Pixels a frame keeps for the one-scale score (a fixed sample: the truth of a long synthetic
#: recording, every pixel of thousands of frames, would not fit in memory).
ONE_SCALE_PIXELS = 2000


def sampled_pairs(
    ours: np.ndarray, truth: np.ndarray, fov: np.ndarray | None, seed: int
) -> tuple[np.ndarray, np.ndarray]:
    """Our depth and the truth's at up to ONE_SCALE_PIXELS of the pixels both have."""
    from endopipe.stages.metrics.depth import valid_depth_pixels

    v = np.flatnonzero(valid_depth_pixels(ours, truth, fov))
    if len(v) > ONE_SCALE_PIXELS:
        v = np.random.default_rng(seed).choice(v, ONE_SCALE_PIXELS, replace=False)
    return ours.reshape(-1)[v], truth.reshape(-1)[v]


def one_scale_abs_rel(
    pairs: dict[int, tuple[np.ndarray, np.ndarray]], poses: list[FramePose]
) -> float | None:
    """AbsRel with one scale for each segment (the median truth-to-ours ratio over all its
    frames), the frames' mean: what a per-frame scale hides, a scale that drifts along the path.
    Segments are scaled apart: their units are not tied to each other."""
    segment = {p.source_index: p.segment for p in poses}
    by_segment: dict[int, list[int]] = {}
    for i in pairs:
        if segment.get(i) is not None:
            by_segment.setdefault(segment[i], []).append(i)
    errors = []
    for frames in by_segment.values():
        s = np.median(np.concatenate([pairs[i][1] / pairs[i][0] for i in frames]))
        errors += [
            float(np.mean(np.abs(s * pairs[i][0] - pairs[i][1]) / pairs[i][1])) for i in frames
        ]
    return float(np.mean(errors)) if errors else None


def pose_every_frame(
    pipe: Pipeline,
    info: CaseInfo,
    windows_dir: Path,
    joined: Joined,
    configs: dict[str, StageConfig],
    ingest,
    staging: Path,
    summary: RecordingSummary,
    console: Console,
) -> list[FramePose]:
    """Every frame between the keyframes posed and given a depth map (recording/depth/, in
    segment 0's units), frames.json written, and the depth scored on all of them."""
    from rich.progress import Progress

    from endopipe.stages.ingest.selection import resize
    from endopipe.stages.io.sources import open_input
    from endopipe.stages.metrics.baselines import brightness_guess
    from endopipe.stages.metrics.depth import affine_invariant_metrics, depth_frame_metrics
    from endopipe.stages.poses.verdict import ranges

    intrinsics = Path(info.intrinsics_file) if info.intrinsics_file else None
    source = open_input(Path(info.input), intrinsics, format=info.kind)
    size = (ingest.width, ingest.height)
    (staging / DEPTH_DIR).mkdir()
    gt = None
    try:
        gt = ingest.ground_truth()
    except InputError:
        pass
    scores: dict[int, dict[str, float]] = {}
    pairs: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # (ours, truth) on sampled pixels
    guesses: dict[int, float] = {}  # the brightness guess, on exactly our pixels
    fov = ingest.fov()
    # A relative ground truth (C3VD's panel, an affine proxy of depth) is scored as the depth
    # stage scores it: AbsRel after a least-squares scale and shift, Spearman, coverage.
    relative = gt is not None and getattr(gt, "kind", "exact") == "relative"
    frame_metrics = affine_invariant_metrics if relative else depth_frame_metrics

    def write_depth(i: int, depth: np.ndarray, rgb: np.ndarray) -> None:
        # float16: 0.05% of the depth, half the disk of float32; scored as stored
        stored = depth.astype(np.float16)
        np.save(staging / DEPTH_DIR / f"{i:06d}.npy", stored)
        depth = stored.astype(np.float32)
        truth = gt.depth(i) if gt is not None else None
        if truth is None:
            return
        if truth.shape != depth.shape:
            truth = cv2.resize(truth, size, interpolation=cv2.INTER_NEAREST)
        truth = truth.astype(np.float32)
        m = frame_metrics(depth, truth, fov)
        if np.isfinite(m["abs_rel"]):
            scores[i] = m
            if not relative:
                pairs[i] = sampled_pairs(depth, truth, fov, seed=i)
            ours = (depth > 0) if fov is None else (depth > 0) & (fov > 0)
            guesses[i] = frame_metrics(brightness_guess(rgb), truth, ours)["abs_rel"]

    # the frames ingest judged (its stride, start and end): kept as keyframes or dropped
    dropped = {i: why for why, idx in ingest.file.dropped_frames.items() for i in idx}
    judged = dropped.keys() | {f.source_index for f in ingest.frames}
    frames_in = (
        (f.source_index, resize(f.rgb, size)) for f in source.frames() if f.source_index in judged
    )
    with Progress(console=console, transient=True) as bar:
        task = bar.add_task("every frame", total=len(judged))
        poses = every_frame(
            pipe,
            frames_in,
            windows_dir,
            joined,
            configs["depth"],
            write_depth,
            lambda: bar.advance(task),
            dropped,
        )
    write_json(staging / FRAMES_FILE, FramesFile(frames=poses).model_dump(mode="json"))
    summary.frames = len(poses)
    summary.frames_posed = sum(p.c2w is not None for p in poses)
    summary.keyframes_doubtful = [p.source_index for p in poses if p.doubt]
    if summary.keyframes_doubtful:
        summary.verdict = "doubtful"
        summary.reasons.append(
            f"keyframes {ranges(summary.keyframes_doubtful)}: registered from the keyframe next to "
            "them, they lie elsewhere than the SfM put them (frames.json says how far)"
        )
    if scores:
        keys = {p.source_index for p in poses if p.kind == "keyframe"}
        summary.depth_gt_kind = "relative" if relative else "exact"
        summary.depth_abs_rel_all_frames = float(np.mean([m["abs_rel"] for m in scores.values()]))
        on_keys = [m["abs_rel"] for i, m in scores.items() if i in keys]
        summary.depth_abs_rel_keyframes = float(np.mean(on_keys)) if on_keys else None
        summary.depth_coverage_all_frames = float(np.mean([m["coverage"] for m in scores.values()]))
        if relative:
            summary.depth_spearman_all_frames = float(
                np.mean([m["spearman"] for m in scores.values()])
            )
        summary.depth_frames_scored = len(scores)
        summary.depth_abs_rel_one_scale = one_scale_abs_rel(pairs, poses)
        summary.brightness_guess_abs_rel = float(np.nanmean(list(guesses.values())))
    return poses
