"""Ground truth of an endopipe case folder (DESIGN §5 `gt/`), used only for evaluation."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np


class GroundTruth:
    """Lazy access to gt/: files are indexed by `source_index` (frame i of the input)."""

    def __init__(self, gt_dir: Path) -> None:
        self.dir = Path(gt_dir)

    def has_poses(self) -> bool:
        return (self.dir / "poses.json").is_file()

    def poses(self) -> list[np.ndarray]:
        data = json.loads((self.dir / "poses.json").read_text())
        if data.get("convention", "opencv_c2w") != "opencv_c2w":
            raise ValueError(f"gt/poses.json convention {data['convention']!r} is not opencv_c2w")
        return [np.array(p, dtype=np.float64) for p in data["poses"]]

    @property
    def units(self) -> str:
        if not self.has_poses():
            return "mm"
        return json.loads((self.dir / "poses.json").read_text()).get("units", "mm")

    def depth(self, source_index: int) -> np.ndarray | None:
        path = self.dir / "depth" / f"{source_index:06d}.npy"
        return np.load(path).astype(np.float32) if path.is_file() else None

    def specular(self, source_index: int) -> np.ndarray | None:
        path = self.dir / "specular" / f"{source_index:06d}.png"
        return cv2.imread(str(path), cv2.IMREAD_GRAYSCALE) if path.is_file() else None

    def mesh_path(self) -> Path | None:
        path = self.dir / "mesh.ply"
        return path if path.is_file() else None

    def centerline(self) -> tuple[np.ndarray, np.ndarray] | None:
        path = self.dir / "centerline.json"
        if not path.is_file():
            return None
        data = json.loads(path.read_text())
        return np.array(data["points"], dtype=np.float64), np.array(
            data["radius"], dtype=np.float64
        )
