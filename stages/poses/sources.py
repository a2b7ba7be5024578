"""Poses from every source but SfM: the ground truth, the input's own poses, a user's file
(matched to the frames by name), or one fixed pose for a camera that stands still."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from endopipe.pipeline.errors import ConfigError, InputError
from endopipe.stages.camera import Camera
from endopipe.stages.ingest.view import IngestView
from endopipe.stages.io.colmap_model import (
    PoseSet,
    camera_to_colmap,
    keep_images,
    read_colmap_model,
    reconstruction_points,
)
from endopipe.stages.io.name_numbers import file_number
from endopipe.stages.io.transforms_json import read_transforms_json
from endopipe.stages.poses.config import PosesConfig
from endopipe.stages.poses.estimate import Estimate
from endopipe.stages.poses.lens import fitted_radius_px
from endopipe.stages.poses.motion import FootageMotion
from endopipe.stages.poses.verdict import FrameVerdict, PoseVerdict


def from_ground_truth(ingest: IngestView, gt_poses: dict[int, np.ndarray] | None) -> Estimate:
    if gt_poses is None:
        raise InputError(
            "poses.source=gt but the input has no ground-truth poses (gt/poses.json, or a data "
            "set's pose files); use poses.source=colmap"
        )
    if ingest.intrinsics is None:
        raise InputError(
            "poses.source=gt needs known intrinsics (intrinsics.json in the case, or "
            "--intrinsics FILE)"
        )
    k = ingest.intrinsics
    return Estimate(
        camera=k, colmap_model=camera_to_colmap(k)[0], c2w=dict(gt_poses), info={"models": 0}
    )


def from_known(ingest: IngestView) -> Estimate:
    """The poses the input came with (not ground truth), as they are: a data set's own account
    of where its camera was, used when SfM cannot say (a still scope, tissue that moves)."""
    known = ingest.known_poses()
    if not known:
        raise InputError(
            "poses.source=known but the input came with no poses of its own (EndoNeRF's "
            "poses_bounds.npy, SCARED's frame_data/); use poses.source=colmap"
        )
    if ingest.intrinsics is None:
        raise InputError(
            "poses.source=known needs known intrinsics (--intrinsics FILE, or the data set's "
            "calibration)"
        )
    k = ingest.intrinsics
    return Estimate(
        camera=k,
        colmap_model=camera_to_colmap(k)[0],
        c2w=dict(known),
        intrinsics_kind="fixed",
        info={"models": 0},
    )


def from_file(ingest: IngestView, cfg: PosesConfig) -> Estimate:
    """Poses from a COLMAP model or a transforms.json. A model's tracks are kept for the frames
    it poses (the SfM-point depth and the lumen fit need them), unless its camera has another
    resolution than the frames."""
    if not cfg.file:
        raise ConfigError(
            "poses.source=file needs --set poses.file=PATH (a COLMAP model folder or "
            "transforms.json)"
        )
    path = Path(cfg.file).expanduser()
    if not path.exists():
        raise InputError(
            f"poses.file not found: {path}; give a COLMAP model folder or transforms.json"
        )
    if path.is_dir() and (path / "transforms.json").is_file():
        if not any(path.glob("cameras.*")) and not (path / "sparse").is_dir():
            path = path / "transforms.json"
    poses = read_transforms_json(path) if path.is_file() else read_colmap_model(path)
    frame_of = match_names(list(poses.c2w), ingest)
    c2w = {i: poses.c2w[name] for name, i in frame_of.items()}
    if not c2w:
        some = ", ".join(list(poses.c2w)[:3])
        raise InputError(
            f"none of the {len(poses.c2w)} images in {path} ({some}, ...) matches a frame; name "
            "them like 01_ingest/frames (000000.png) or like the input's files"
        )
    w, h = ingest.width, ingest.height
    if poses.camera is not None and poses.colmap_model is not None:
        cam = poses.camera
        if abs(cam.width / cam.height - w / h) > 0.01:
            raise InputError(
                f"the camera in {path} is {cam.width}x{cam.height} but the frames are {w}x{h}; "
                "give poses estimated on these frames"
            )
        camera, model = (
            (cam if (cam.width, cam.height) == (w, h) else cam.scaled(w, h)),
            (poses.colmap_model),
        )
        kind = "from file"
    elif ingest.intrinsics is not None:
        camera, model = ingest.intrinsics, camera_to_colmap(ingest.intrinsics)[0]
        kind = "fixed"
    else:
        raise InputError(
            f"{path} gives no intrinsics and none are known; add fl_x, fl_y, cx, cy, w, h to it or "
            "pass --intrinsics FILE"
        )
    est = Estimate(
        camera=camera,
        colmap_model=model,
        c2w=c2w,
        xyz=poses.xyz,
        rgb=poses.rgb,
        intrinsics_kind=kind,
        info={"models": 1, "file": str(path)},
    )
    rec = poses.reconstruction
    model_size = (poses.camera.width, poses.camera.height) if poses.camera else None
    if rec is not None and rec.num_points3D() and model_size == (w, h):
        names = {i: name for name, i in ingest.index_by_name().items()}
        keep_images(rec, {name: names[i] for name, i in frame_of.items()})
        est.xyz, est.rgb = reconstruction_points(rec)
        est.reconstruction = rec
        if kind == "from file":  # the lens may have been estimated: where its tracks reach
            est.fitted_radius_px = fitted_radius_px(rec)
    return est


def match_frames(poses: PoseSet, ingest: IngestView) -> dict[int, np.ndarray]:
    """A file's poses by endopipe frame index (see `match_names`)."""
    return {i: poses.c2w[name] for name, i in match_names(list(poses.c2w), ingest).items()}


def match_names(names: list[str], ingest: IngestView) -> dict[str, int]:
    """Map a file's image names to endopipe frames: the strategy matching the most frames wins.

    By endopipe name (000000.png), by the input's own file names (image folders), or by the
    number in the name read as the frame's position in the input (source_index).
    """
    by_name = ingest.index_by_stem()
    by_source_index = ingest.index_by_source_index()
    by_source_name = ingest.index_by_source_stem()
    candidates = []
    for table in (by_name, by_source_name):
        candidates.append({n: table[Path(n).stem] for n in names if Path(n).stem in table})
    numbers = {n: file_number(n) for n in names}
    if len(set(numbers.values())) == len(numbers):
        candidates.append(
            {n: by_source_index[v] for n, v in numbers.items() if v in by_source_index}
        )
    return max(candidates, key=len)


def from_still_camera(ingest: IngestView, cfg: PosesConfig, motion: FootageMotion) -> Estimate:
    """One fixed pose for every frame: a still camera has no path, and SfM would make one of
    the tissue's motion. Without known intrinsics the lens is assumed (nothing here could
    measure it) and the summary says so; there are no sparse points (no parallax)."""
    known = ingest.intrinsics
    camera = known if known is not None else assumed_camera(ingest, cfg.motion.assumed_hfov_deg)
    kind = "fixed" if known is not None else "assumed"
    c2w = {f.index: np.eye(4) for f in ingest.frames}
    lens = (
        ""
        if known is not None
        else (
            f"; intrinsics assumed ({cfg.motion.assumed_hfov_deg:g} deg horizontal field of view: "
            "give --intrinsics FILE for the real lens)"
        )
    )
    verdict = PoseVerdict(
        status="ok",
        reasons=[f"{motion.label}: one fixed pose for all {len(c2w)} frames{lens}", motion.said],
        mapper="still camera",
        frames=[FrameVerdict(index=i, status="ok") for i in sorted(c2w)],
    )
    return Estimate(
        camera=camera,
        colmap_model=camera_to_colmap(camera)[0],
        c2w=c2w,
        intrinsics_kind=kind,
        verdict=verdict,
        info={"models": 1, "mapper": "still camera"},
    )


def from_one_pair(ingest: IngestView) -> Estimate:
    """A stereo pair alone: its left camera is the world (one view has no path to pose), in the
    rig's millimetres; a second frame of a two-frame input stays unposed (nothing relates it
    to the first but a guess)."""
    camera = ingest.intrinsics
    if camera is None:  # ingest matched the pair: it had the rectified camera
        raise InputError("a stereo pair alone needs its rectified camera (--intrinsics)")
    first = ingest.frames[0].index
    said = f"one stereo pair: frame {first}'s left camera is the world, in the rig's mm" + (
        f"; {len(ingest.frames) - 1} other frame(s) not posed" if len(ingest.frames) > 1 else ""
    )
    verdict = PoseVerdict(
        status="not assessed",  # one pose by definition: no path to be right or wrong
        reasons=[said],
        mapper="one stereo pair",
        frames=[FrameVerdict(index=first, status="ok")],
    )
    return Estimate(
        camera=camera,
        colmap_model=camera_to_colmap(camera)[0],
        c2w={first: np.eye(4)},
        verdict=verdict,
        info={"models": 1, "mapper": "one stereo pair"},
    )


def assumed_camera(ingest: IngestView, hfov_deg: float) -> Camera:
    """A pinhole with the principal point at the centre and the given horizontal field of view."""
    w, h = ingest.width, ingest.height
    f = 0.5 * w / np.tan(np.radians(hfov_deg) / 2)
    return Camera(width=w, height=h, fx=f, fy=f, cx=(w - 1) / 2, cy=(h - 1) / 2)
