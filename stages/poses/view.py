"""`02_poses/cameras.json` (docs/formats.md) and the typed view downstream stages use."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from pydantic import BaseModel, Field, model_validator

from endopipe.pipeline.cache import Manifest
from endopipe.pipeline.stage import read_summary
from endopipe.stages.camera import Camera
from endopipe.stages.io.colmap_model import camera_from_colmap, camera_to_colmap
from endopipe.stages.poses.lens import past_fitted_radius
from endopipe.stages.poses.motion import FootageMotion
from endopipe.stages.poses.summary import PosesSummary
from endopipe.stages.poses.verdict import PoseVerdict

if TYPE_CHECKING:
    import pycolmap


class FramePose(BaseModel):
    index: int
    registered: bool
    c2w: list[list[float]] | None = None


#: cameras.json's `source` for a stereo pair alone (poses/sources.py: from_one_pair).
ONE_PAIR_SOURCE = "one stereo pair"


class CamerasFile(BaseModel):
    """One shared camera and a camera-to-world pose per frame (OpenCV convention).

    The camera is `intrinsics()`, one `Camera` with its lens distortion, stored with the keys
    of docs/formats.md: `model` + `params` are the COLMAP camera (distortion included) and
    width..cy its pinhole part in OpenCV's pixel convention, for tools that read only those.
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    model: str = Field("PINHOLE", description="COLMAP camera model")
    params: list[float] = Field(
        default_factory=list,
        description="COLMAP camera params (principal point + 0.5); empty = PINHOLE of fx..cy.",
    )
    metric: bool = False
    units: str = "colmap"
    source: str = "colmap"
    fitted_radius_px: float | None = Field(
        None,
        description="An estimated lens: how far from the principal point (px) the tracked "
        "features it was fitted to reach; past it the lens is extrapolated. None: given.",
    )
    frames: list[FramePose]

    @model_validator(mode="after")
    def _one_camera(self) -> CamerasFile:
        """fx..cy and model + params are one camera, never two that disagree."""
        k = self.intrinsics()
        got, want = (self.fx, self.fy, self.cx, self.cy), (k.fx, k.fy, k.cx, k.cy)
        if not np.allclose(got, want, rtol=1e-9, atol=1e-9):
            raise ValueError(f"fx, fy, cx, cy {got} are not those of the {self.model} params")
        return self

    def intrinsics(self) -> Camera:
        """The camera, with its lens distortion."""
        if not self.params:
            return Camera(
                width=self.width, height=self.height, fx=self.fx, fy=self.fy, cx=self.cx, cy=self.cy
            )
        return camera_from_colmap(self.model, self.width, self.height, self.params)

    @classmethod
    def build(
        cls,
        camera: Camera,
        poses: dict[int, np.ndarray],
        n_frames: int,
        *,
        colmap_model: str | None = None,
        metric: bool,
        source: str,
        fitted_radius_px: float | None = None,
    ) -> CamerasFile:
        """`colmap_model`: the COLMAP model to give the camera as (default: the smallest that
        holds its lens)."""
        model, params = camera_to_colmap(camera, colmap_model)
        return cls(
            width=camera.width,
            height=camera.height,
            fx=camera.fx,
            fy=camera.fy,
            cx=camera.cx,
            cy=camera.cy,
            model=model,
            params=params,
            metric=metric,
            units="mm" if metric else "colmap",
            source=source,
            fitted_radius_px=fitted_radius_px,
            frames=[
                FramePose(
                    index=i,
                    registered=i in poses,
                    c2w=np.asarray(poses[i]).tolist() if i in poses else None,
                )
                for i in range(n_frames)
            ],
        )


@dataclass
class SparseObservations:
    """Every image observation of a sparse SfM point: which frame saw it, where (OpenCV pixel
    convention, the top-left pixel's centre at (0, 0)), the point, its track length and mean
    reprojection error (px). Arrays of one length N."""

    frame: np.ndarray  # (N,) endopipe frame index
    uv: np.ndarray  # (N, 2)
    xyz: np.ndarray  # (N, 3) world, the cameras.json frame
    track: np.ndarray  # (N,) images that see the point
    error: np.ndarray  # (N,) px
    angle: np.ndarray  # (N,) widest angle between two of the point's viewing rays (degrees)

    def resize(self, size: tuple[int, int], to: tuple[int, int]) -> None:
        """Move the pixels from a (width, height) grid onto another (the poses' camera may
        have another resolution than the working frames); pixel centres map to centres."""
        if size != to:
            self.uv = (self.uv + 0.5) * np.array([to[0] / size[0], to[1] / size[1]]) - 0.5


class PosesView:
    """Typed access to 02_poses: the camera (with its lens), registered frames' c2w, sparse
    points."""

    def __init__(self, folder: Path) -> None:
        self.folder = Path(folder)
        self.file = CamerasFile.model_validate_json((self.folder / "cameras.json").read_text())
        self.intrinsics: Camera = self.file.intrinsics()  # the one camera, distortion included
        self.metric = self.file.metric
        self.c2w: dict[int, np.ndarray] = {
            f.index: np.array(f.c2w, dtype=np.float64) for f in self.file.frames if f.registered
        }

    @cached_property
    def summary(self) -> PosesSummary:
        """The stage's summary in its manifest, as the model the stage wrote (SummaryMismatch
        when the folder was written with other fields)."""
        return read_summary(self.folder, PosesSummary)

    @property
    def motion(self) -> FootageMotion | None:
        """The footage's motion as the poses stage judged it (docs/formats.md). None: not
        judged, or a folder put together by hand, with no manifest."""
        if Manifest.load(self.folder) is None:
            return None
        return self.summary.motion

    @property
    def in_gt_frame(self) -> bool:
        """Metric poses in the ground truth's world frame (aligned to it), not only in its
        units: a stereo rig's scale gives millimetres in the poses' own frame. A folder with
        no manifest, or written before the scale had a source, is metric by alignment."""
        if not self.metric:
            return False
        if Manifest.load(self.folder) is None:
            return True
        return self.summary.metric_from in (None, "ground truth")

    @property
    def one_pair(self) -> bool:
        """A stereo pair alone: one frame posed as the world, no path (`source` says so)."""
        return self.file.source == ONE_PAIR_SOURCE

    @property
    def still(self) -> bool:
        """The camera stood still: one pose for every frame, nothing seen from two places."""
        motion = self.motion
        return motion is not None and motion.camera == "still"

    @property
    def registered(self) -> list[int]:
        return sorted(self.c2w)

    def centres(self) -> np.ndarray:
        """Camera centres of the registered frames, in frame order (Nx3)."""
        return np.array([self.c2w[i][:3, 3] for i in self.registered]).reshape(-1, 3)

    @property
    def points_path(self) -> Path:
        """points.ply: the sparse 3D points (absent when the source gave none)."""
        return self.folder / "points.ply"

    @property
    def sparse_dir(self) -> Path:
        """sparse/: the COLMAP model with its tracks (absent when the poses came without)."""
        return self.folder / "sparse"

    def past_fitted_radius(self, camera: Camera, share: float = 1.0) -> np.ndarray | None:
        """The pixels of `camera`'s image (this camera at any size) past `share` of the radius
        the estimated lens was fitted within: its rays there are the lens extrapolated. None
        when the lens was given."""
        return past_fitted_radius(camera, self.file.fitted_radius_px, self.file.width, share)

    def verdict(self) -> PoseVerdict | None:
        """verdict.json: ok / doubtful for the sequence and each frame, with the reasons (None
        for a folder written before the verdict existed)."""
        path = self.folder / "verdict.json"
        if not path.is_file():
            return None
        return PoseVerdict.model_validate_json(path.read_text())

    def points(self) -> np.ndarray:
        """Sparse 3D points (Nx3) from points.ply; empty when the source gave none."""
        path = self.points_path
        if not path.is_file():
            return np.zeros((0, 3))
        import trimesh

        cloud = trimesh.load(path, process=False)
        return np.asarray(getattr(cloud, "vertices", np.zeros((0, 3))), dtype=np.float64)

    def observations(self, index_of: dict[str, int]) -> SparseObservations | None:
        """The sparse model's 2D-3D observations (sparse/, same world frame as cameras.json);
        `index_of` maps an image file name to its frame index. None without a model or
        tracks (e.g. poses from a transforms.json)."""
        folder = self.sparse_dir
        if not (folder / "points3D.txt").is_file() and not (folder / "points3D.bin").is_file():
            return None
        import pycolmap  # cv2 is already imported through the `endopipe.stages` package

        return reconstruction_observations(
            pycolmap.Reconstruction(str(folder)), index_of, set(self.c2w)
        )


def reconstruction_observations(
    rec: pycolmap.Reconstruction, index_of: dict[str, int], registered: set[int]
) -> SparseObservations | None:
    """A model's 2D-3D observations in the frames of `registered` (frame indices; `index_of`
    maps an image file name to its index); None when it has none."""
    angles = triangulation_angles(rec)
    rows: list[tuple] = []
    for img in rec.images.values():
        idx = index_of.get(Path(img.name).name)
        if idx is None or idx not in registered:
            continue
        for p2 in img.points2D:
            if p2.has_point3D():
                pt = rec.points3D[p2.point3D_id]
                u, v = p2.xy
                rows.append(
                    (
                        idx,
                        u - 0.5,
                        v - 0.5,
                        *pt.xyz,
                        pt.track.length(),
                        pt.error,
                        angles[p2.point3D_id],
                    )
                )
    if not rows:
        return None
    a = np.array(rows, dtype=np.float64)
    return SparseObservations(
        frame=a[:, 0].astype(np.int64),
        uv=a[:, 1:3],
        xyz=a[:, 3:6],
        track=a[:, 6],
        error=a[:, 7],
        angle=a[:, 8],
    )


def triangulation_angles(rec: pycolmap.Reconstruction) -> dict[int, float]:
    """Each sparse point's widest angle between the rays of two cameras that see it (degrees):
    how well its depth is determined. Points seen down the direction of travel are seen under
    a few degrees, and their depth comes out short (60-frame colon, the far end in the last
    frame: 0.88 of the truth under 2 degrees, 0.92 at 2-4, 0.96 at 4-8)."""
    centres = {img.image_id: np.asarray(img.projection_center()) for img in rec.images.values()}
    out: dict[int, float] = {}
    for pid, pt in rec.points3D.items():
        seen_from = [centres[e.image_id] for e in pt.track.elements if e.image_id in centres]
        if len(seen_from) < 2:  # one ray: no angle, the depth is not determined
            out[pid] = 0.0
            continue
        rays = np.array(seen_from) - np.asarray(pt.xyz)
        rays /= np.linalg.norm(rays, axis=1, keepdims=True).clip(1e-12)
        out[pid] = float(np.degrees(np.arccos(np.clip(rays @ rays.T, -1.0, 1.0).min())))
    return out
