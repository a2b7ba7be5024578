"""What every export format reads: a case's registered frames, through its stages' views.

The poses are those the depth maps and the mesh were made at: `NerfView.c2w`, the NeRF's refined
poses when it refined them, else 02_poses'. The camera is 02_poses' with its lens, scaled to the
exported (01_ingest) images. Writing depth at one pose and a pose from another file would put
every exported point off by the refinement.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypeVar

import numpy as np

from endopipe.pipeline.errors import EndopipeError
from endopipe.stages.camera import Camera
from endopipe.stages.depth.view import DepthView
from endopipe.stages.ingest.view import IngestView
from endopipe.stages.nerf.view import NerfView
from endopipe.stages.poses.view import PosesView

V = TypeVar("V")


@dataclass
class ExportResult:
    format: str
    out: Path
    frames: int
    files: list[str]
    notes: list[str] = field(default_factory=list)


@dataclass
class ExportFrame:
    index: int
    source_index: int
    image: Path | None
    mask: Path | None
    has_depth: bool
    c2w: np.ndarray  # OpenCV camera-to-world: the pose the frame's depth was rendered at


@dataclass
class CaseExport:
    """What every format needs: the camera at image resolution, the registered frames at the
    poses of depth and mesh, and the views of the stages that wrote them."""

    case_dir: Path
    folders: dict[str, Path]
    poses: PosesView
    intrinsics: Camera  # at the exported images' resolution, with its lens distortion
    frames: list[ExportFrame]
    skipped: list[int]
    depth_view: DepthView | None = None
    refined: bool = False  # the poses are the NeRF's refined ones (04_nerf/cameras_refined.json)

    @property
    def metric(self) -> bool:
        return self.poses.metric

    @property
    def units(self) -> str:
        return "mm" if self.poses.metric else self.poses.file.units

    @property
    def poses_source(self) -> str:
        if self.refined:
            return "refined by the NeRF (04_nerf/cameras_refined.json), as depth and mesh use them"
        return "02_poses/cameras.json"

    def has_depth(self) -> bool:
        return any(f.has_depth for f in self.frames)

    def depth(self, frame: ExportFrame) -> np.ndarray:
        """The frame's z-depth map from 05_depth (only for frames with `has_depth`)."""
        assert self.depth_view is not None and frame.has_depth
        return self.depth_view.depth(frame.index)

    def view(self, stage: str, reader: Callable[[Path], V]) -> V | None:
        """Another stage's view (mesh, centerline), or None when the case has not run it."""
        return stage_view(self.folders, stage, reader)


def stage_view(folders: Mapping[str, Path], stage: str, reader: Callable[[Path], V]) -> V | None:
    """The view of a stage's published folder, or None when the case has not run it."""
    folder = folders.get(stage)
    if folder is None or not Path(folder).is_dir():
        return None
    try:
        return reader(Path(folder))
    except FileNotFoundError:
        return None


def load_case_export(case_dir: Path, folders: Mapping[str, Path]) -> CaseExport:
    """The case's registered frames, read through the stage views; `folders` maps a stage name
    to its published folder (the engine's `Pipeline.folders`)."""
    case_dir = Path(case_dir)
    folders = {name: Path(f) for name, f in folders.items()}
    poses = stage_view(folders, "poses", PosesView)
    if poses is None:
        raise EndopipeError(
            f"{case_dir.name} has no camera poses (02_poses/cameras.json); run "
            "`endopipe run INPUT --until poses` first"
        )
    ingest = stage_view(folders, "ingest", IngestView)
    depth = stage_view(folders, "depth", DepthView)
    nerf = stage_view(folders, "nerf", NerfView)
    c2w = nerf.c2w(poses) if nerf is not None else poses.c2w
    cams = poses.file
    size = (ingest.width, ingest.height) if ingest is not None else (cams.width, cams.height)
    k = poses.intrinsics
    if (k.width, k.height) != size:
        k = k.scaled(*size)
    with_depth = set(depth.indices) if depth is not None else set()
    frames, skipped = [], []
    for fp in cams.frames:
        if fp.index not in c2w:
            skipped.append(fp.index)
            continue
        kept = ingest is not None and ingest.has_frame(fp.index)
        image = ingest.image_path(fp.index) if kept else None
        mask = ingest.mask_path(fp.index) if kept else None
        frames.append(
            ExportFrame(
                index=fp.index,
                source_index=ingest.frame(fp.index).source_index if kept else fp.index,
                image=image if image is not None and image.is_file() else None,
                mask=mask if mask is not None and mask.is_file() else None,
                has_depth=fp.index in with_depth,
                c2w=c2w[fp.index],
            )
        )
    if not frames:
        raise EndopipeError(f"{case_dir.name}: no registered frame in 02_poses/cameras.json")
    refined = nerf is not None and nerf.refined_cameras is not None
    return CaseExport(case_dir, folders, poses, k, frames, skipped, depth, refined)


def place(src: Path, dst: Path, symlink: bool) -> None:
    """Copy (or symlink) one file into the export."""
    dst.parent.mkdir(parents=True, exist_ok=True)
    if symlink:
        dst.symlink_to(src.resolve())
    else:
        shutil.copy2(src, dst)


def need_images(case: CaseExport) -> None:
    missing = [f.index for f in case.frames if f.image is None]
    if missing:
        raise EndopipeError(
            f"{case.case_dir.name}: frame image(s) missing for {len(missing)} registered frame(s) "
            "(01_ingest/frames/); re-run `endopipe run INPUT --until ingest`"
        )
