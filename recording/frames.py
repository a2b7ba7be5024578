"""A pose and a depth map for every frame of a recording, not only its keyframes.

A frame between two keyframes is registered against the window that posed them: corners of
each neighbouring keyframe that the window's depth map places in 3D are tracked into the frame
(Lucas-Kanade, forward-backward checked), and its pose is the PnP fit of those 2D-3D matches
(OpenCV, RANSAC, started at the keyframe's pose). Its depth is then rendered from that window's
field, as the depth stage renders a keyframe's. A frame that does not register (washed out, too
few tracked corners) gets no pose and no depth: unknown, never interpolated.

Frames stream from the input once, in order; one window's baked field is held at a time.
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


class FramePose(BaseModel):
    """recording/frames.json: one line per frame from the first keyframe to the last."""

    source_index: int
    window: str | None
    kind: str  # keyframe | registered | unregistered
    inliers: int | None = None
    c2w: list[list[float]] | None = None  # segment 0's frame and units


class FramesFile(BaseModel):
    """recording/frames.json: every frame from the first keyframe to the last."""

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


def register(grey: np.ndarray, refs: list[Reference], camera: Camera) -> tuple[Any, int]:
    """The frame's c2w in the references' frame (None: it does not register) and the inliers."""
    obj, img = [], []
    for ref in refs:
        usable = ((ref.depth > 0) * 255).astype(np.uint8)
        corners = cv2.goodFeaturesToTrack(ref.grey, 400, 0.01, 5, mask=usable)
        if corners is None:
            continue
        found, ok = track_corners(ref.grey, grey, corners.astype(np.float32), 1.0)
        if not ok.any():
            continue
        uv = corners.reshape(-1, 2)[ok]
        z = ref.depth[uv[:, 1].round().astype(int), uv[:, 0].round().astype(int)]
        keep = z > 0
        d = pixel_directions(camera, uv[keep, 0], uv[keep, 1]) * z[keep, None]
        obj.append(d @ ref.c2w[:3, :3].T + ref.c2w[:3, 3])
        seen = found.reshape(-1, 2)[ok][keep]
        img.append(pixel_directions(camera, seen[:, 0], seen[:, 1])[:, :2])
    if not obj or sum(len(o) for o in obj) < MIN_INLIERS:
        return None, 0
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
        return None, 0 if inliers is None else len(inliers)
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = cv2.Rodrigues(rvec)[0], tvec.reshape(3)
    return np.linalg.inv(out), len(inliers)


def every_frame(
    pipe: Pipeline,
    frames_in: Iterator[tuple[int, np.ndarray]],
    windows_dir: Path,
    joined: Joined,
    depth_cfg: Any,
    write_depth: Callable[[int, np.ndarray, np.ndarray], None],
    progress: Callable[[], None] = lambda: None,
) -> list[FramePose]:
    """Pose (and, through `write_depth(source_index, depth, rgb)`, the depth map in segment 0's
    units) of every frame from `frames_in` ((source_index, RGB at the working size)) between
    segment 0's first and last keyframes."""
    keys = {f.source_index: f for f in joined.frames if f.segment == 0}
    order = sorted(keys)
    if not order:
        return []
    sights: dict[str, WindowSight] = {}
    out: list[FramePose] = []
    for source_index, rgb in frames_in:
        if source_index < order[0] or source_index > order[-1]:
            continue
        progress()
        before = order[np.searchsorted(order, source_index, side="right") - 1]
        after = order[min(np.searchsorted(order, source_index), len(order) - 1)]
        name = keys[before].window
        if name not in sights:
            sights.clear()  # one window's field in memory at a time
            sights[name] = WindowSight(pipe, windows_dir / name, depth_cfg)
        sight = sights[name]
        if source_index in keys and keys[source_index].window == name:
            c2w, kind, inliers = sight.c2w[sight.index[source_index]], "keyframe", None
        else:
            refs = [r for k in {before, after} if (r := sight.reference(k)) is not None]
            grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
            c2w, inliers = register(grey, refs, sight.camera) if refs else (None, 0)
            kind = "registered" if c2w is not None else "unregistered"
        if c2w is None:
            out.append(
                FramePose(source_index=source_index, window=name, kind=kind, inliers=inliers)
            )
            continue
        depth = sight.render(sight.camera, c2w, None, colour=False)["depth"]
        scale = np.float32(joined.depth_scale(name, source_index))
        write_depth(source_index, (depth * scale).astype(np.float32), rgb)
        out.append(
            FramePose(
                source_index=source_index,
                window=name,
                kind=kind,
                inliers=inliers,
                c2w=joined.place(name, source_index, c2w).tolist(),
            )
        )
    return out


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
            ours = (depth > 0) if fov is None else (depth > 0) & (fov > 0)
            guesses[i] = frame_metrics(brightness_guess(rgb), truth, ours)["abs_rel"]

    frames_in = ((f.source_index, resize(f.rgb, size)) for f in source.frames())
    seg = [f.source_index for f in joined.frames if f.segment == 0]
    total = (max(seg) - min(seg) + 1) if seg else 0
    with Progress(console=console, transient=True) as bar:
        task = bar.add_task("every frame", total=total)
        poses = every_frame(
            pipe,
            frames_in,
            windows_dir,
            joined,
            configs["depth"],
            write_depth,
            lambda: bar.advance(task),
        )
    write_json(staging / FRAMES_FILE, FramesFile(frames=poses).model_dump(mode="json"))
    summary.frames = len(poses)
    summary.frames_posed = sum(p.c2w is not None for p in poses)
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
        summary.brightness_guess_abs_rel = float(np.nanmean(list(guesses.values())))
    return poses
