"""C3VD's layout written frame by frame (`endopipe synth --layout c3vd`): what stages/io/c3vd.py
reads, so a synthetic case goes through the same reader, calibration and truth mesh as a
downloaded sequence.

```
0000_color.png ...       the frames
0000_depth.tiff ...      uint16 z-depth, mm = v * 100 / 65535 (0: none; 65535: 100 mm or more)
pose.txt                 camera-to-world per frame, 16 values column-major, mm
calib_results.txt        the synthetic lens as OCamCalib's export (ocam.ocam_from_camera), or
                         with C3VD's own lens (`--lens c3vd`) its published calibration in
                         ../cfhq190l_omnidirectional_params/ beside the sequence (c3vd_lens.py)
coverage_mesh.obj        the scene's surface in the pose frame (mm): the truth the mesh is scored on
```
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import trimesh

from endopipe.stages.camera import Camera
from endopipe.stages.io.c3vd import MESH_FILES, encode_depth, format_pose_line
from endopipe.stages.io.ocam import ocam_from_camera, write_ocamcalib
from endopipe.synth.c3vd_lens import write_params_folder

CALIBRATION_FILE = "calib_results.txt"


class C3VDSink:
    """Frames, depth and poses as C3VD ships them, with its calibration and model mesh."""

    def __init__(self, out: Path, camera: Camera, shipped_lens: bool = False) -> None:
        self.out, self.camera = Path(out), camera
        self.out.mkdir(parents=True, exist_ok=True)
        if shipped_lens:  # C3VD's calibration as it ships, for the sequences beside it
            write_params_folder(self.out.parent, camera.width, camera.height)
        else:
            write_ocamcalib(self.out / CALIBRATION_FILE, ocam_from_camera(camera))
        self.count = 0

    def add_frame(
        self,
        rgb: np.ndarray,
        depth: np.ndarray,
        tool: np.ndarray | None,
        right: np.ndarray | None = None,
    ) -> None:
        name = f"{self.count:04d}"
        cv2.imwrite(str(self.out / f"{name}_color.png"), rgb[:, :, ::-1])
        cv2.imwrite(str(self.out / f"{name}_depth.tiff"), encode_depth(depth))
        self.count += 1

    def add_surface(self, vertices: np.ndarray, faces: np.ndarray) -> None:
        """The scene's surface (mm, world = pose frame) as the registered model."""
        mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=False)
        mesh.export(self.out / MESH_FILES[0])

    def finish(self, poses: np.ndarray) -> None:
        lines = [format_pose_line(p) for p in poses]
        (self.out / "pose.txt").write_text("\n".join(lines) + "\n")
