"""`02_poses/cameras.json` (DESIGN §3 file contract) and the typed view downstream stages use."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from pydantic import BaseModel, Field

from stages.geometry import Intrinsics


class FramePose(BaseModel):
    index: int
    registered: bool
    c2w: list[list[float]] | None = None


class CamerasFile(BaseModel):
    """One shared pinhole camera and a camera-to-world pose per frame (OpenCV convention)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    model: str = "PINHOLE"
    params: list[float] = Field(
        default_factory=list, description="COLMAP camera params as estimated."
    )
    metric: bool = False
    units: str = "colmap"
    source: str = "colmap"
    frames: list[FramePose]

    def intrinsics(self) -> Intrinsics:
        return Intrinsics(
            width=self.width, height=self.height, fx=self.fx, fy=self.fy, cx=self.cx, cy=self.cy
        )

    @classmethod
    def build(
        cls,
        intrinsics: Intrinsics,
        poses: dict[int, np.ndarray],
        n_frames: int,
        *,
        model: str = "PINHOLE",
        params: list[float] | None = None,
        metric: bool,
        source: str,
    ) -> CamerasFile:
        return cls(
            width=intrinsics.width,
            height=intrinsics.height,
            fx=intrinsics.fx,
            fy=intrinsics.fy,
            cx=intrinsics.cx,
            cy=intrinsics.cy,
            model=model,
            params=params or [],
            metric=metric,
            units="mm" if metric else "colmap",
            source=source,
            frames=[
                FramePose(
                    index=i,
                    registered=i in poses,
                    c2w=np.asarray(poses[i]).tolist() if i in poses else None,
                )
                for i in range(n_frames)
            ],
        )


class PosesView:
    """Typed access to 02_poses: intrinsics, registered frames' c2w, sparse points."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.file = CamerasFile.model_validate_json((folder / "cameras.json").read_text())
        self.intrinsics = self.file.intrinsics()
        self.metric = self.file.metric
        self.c2w: dict[int, np.ndarray] = {
            f.index: np.array(f.c2w, dtype=np.float64) for f in self.file.frames if f.registered
        }

    @property
    def registered(self) -> list[int]:
        return sorted(self.c2w)

    def centres(self) -> np.ndarray:
        """Camera centres of the registered frames, in frame order (Nx3)."""
        return np.array([self.c2w[i][:3, 3] for i in self.registered]).reshape(-1, 3)

    def points(self) -> np.ndarray:
        """Sparse 3D points (Nx3) from points.ply; empty when the source gave none."""
        path = self.folder / "points.ply"
        if not path.is_file():
            return np.zeros((0, 3))
        import trimesh

        cloud = trimesh.load(path, process=False)
        return np.asarray(getattr(cloud, "vertices", np.zeros((0, 3))), dtype=np.float64)
