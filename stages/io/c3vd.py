"""C3VD (Colonoscopy 3D Video Dataset): one sequence per folder, read in place.

```
cecum_t1_a/
  0000_color.png ...     frames (endopipe's source_index = position in numeric order)
  0000_depth.tiff ...    uint16 z-depth: depth_mm = v * 100 / 65535 (0 = invalid)
  pose.txt               one line per frame: 16 comma-separated values, column-major,
                         camera-to-world, millimetres
  coverage_mesh.obj      the registered model in the pose frame (mm): the mesh stage's truth
                         (`outputMesh.obj` in the first release)
  intrinsics.json        optional, endopipe format: used as given
```

The scope's calibration is one for the whole data set (Scaramuzza's omnidirectional model, read
by `ocam.read_ocam`): `calib_results.txt`, `camera_intrinsics.txt`, `config.ini` or
`*omnidirectional*.txt` (the values; the `*_format.txt` beside them names them), in the sequence
folder, its parent or grandparent, or in a `*omnidirectional_params/` folder there. Without
intrinsics.json the lens is OpenCV's fisheye fitted to it (`ocam.fit_fisheye`), and its residual
is said in one line.

`coverage_mesh.obj` is DurrLab/C3VD's `rendergt` output (RenderingModule::writeOBJ): the model's
vertices moved by the registration into the frame of pose.txt, its texture coordinates the
coverage; `model.obj` of a registration folder is still in the model's own frame and is not
read. pose.txt is that program's camera-to-world, written column-major.

File-name zero padding differs between copies (`0_color.png`, `0000_color.png`): files are
globbed and sorted by their number, and pose line n belongs to frame number n.
"""

from __future__ import annotations

import re
from functools import lru_cache
from pathlib import Path

import numpy as np
from PIL import Image

from endopipe.pipeline.errors import InputError
from endopipe.stages.camera import Camera
from endopipe.stages.io.frame_truth import NumberedGroundTruth, numbered
from endopipe.stages.io.images import ImageListSource
from endopipe.stages.io.intrinsics import load_intrinsics_file
from endopipe.stages.io.ocam import LensFit, OcamLens, fit_fisheye, read_ocam

NAME = "c3vd"
LAYOUT = "a folder of NNNN_color.png with NNNN_depth.tiff and pose.txt"
GT_KIND = "exact"
COLOR = re.compile(r"^(\d+)_color\.png$", re.IGNORECASE)
DEPTH = re.compile(r"^(\d+)_depth\.tiff?$", re.IGNORECASE)
DEPTH_RANGE_MM = 100.0  # uint16 full scale
#: The registered model in the pose frame, by release (first: the current name).
MESH_FILES = ("coverage_mesh.obj", "outputMesh.obj")
#: The omnidirectional calibration's names, in the order they are looked for.
CALIBRATION_FILES = ("calib_results.txt", "camera_intrinsics.txt", "config.ini")
CALIBRATION_GLOB = "*omnidirectional*.txt"


def is_sequence(path: Path) -> bool:
    return path.is_dir() and any(COLOR.match(p.name) for p in path.iterdir())


def decode_depth(raw: np.ndarray) -> np.ndarray:
    """uint16 tiff values -> float32 mm; 0 (no surface) and 65535 (clamped at 100 mm: deeper,
    by how much unknown) are invalid, as DurrLab/C3VD's python/exampleDataLoader.py reads them."""
    mm = raw.astype(np.float64) * (DEPTH_RANGE_MM / 65535.0)
    return np.where(raw >= 65535, 0.0, mm).astype(np.float32)


def encode_depth(depth_mm: np.ndarray) -> np.ndarray:
    """float mm -> the dataset's uint16 encoding (quantisation step 100/65535 mm)."""
    v = np.round(np.asarray(depth_mm, np.float64) * (65535.0 / DEPTH_RANGE_MM))
    return np.clip(v, 0, 65535).astype(np.uint16)


def parse_pose_line(line: str) -> np.ndarray:
    """16 comma-separated values, column-major -> 4x4 camera-to-world (mm)."""
    values = [float(v) for v in line.replace(",", " ").split()]
    if len(values) != 16:
        raise ValueError(f"expected 16 values, got {len(values)}")
    return np.array(values, dtype=np.float64).reshape(4, 4).T


def format_pose_line(c2w: np.ndarray) -> str:
    """The inverse of parse_pose_line: a 4x4 written column-major, comma-separated."""
    return ",".join(repr(float(v)) for v in np.asarray(c2w, np.float64).T.reshape(-1))


def read_poses(path: Path) -> list[np.ndarray]:
    poses = []
    for n, line in enumerate(path.read_text().splitlines(), start=1):
        if not line.strip():
            continue
        try:
            poses.append(parse_pose_line(line))
        except ValueError as e:
            raise InputError(f"{path} line {n}: {e}; C3VD poses are 16 values a line") from None
    return poses


def find_intrinsics(seq: Path) -> Camera | None:
    for folder in (seq, seq.parent):
        if (folder / "intrinsics.json").is_file():
            return load_intrinsics_file(folder / "intrinsics.json")
    return None


def find_calibration(seq: Path) -> Path | None:
    """The data set's omnidirectional calibration nearest the sequence (module docstring)."""
    for folder in (seq, seq.parent, seq.parent.parent):
        for where in (folder, *sorted(folder.glob("*omnidirectional_params"))):
            for name in CALIBRATION_FILES:
                if (where / name).is_file():
                    return where / name
            # The values, not the format file that names them (ocam.read_ocam reads it too).
            found = sorted(p for p in where.glob(CALIBRATION_GLOB) if "format" not in p.name)
            if found:
                return found[0]
    return None


def find_mesh(seq: Path) -> Path | None:
    for name in MESH_FILES:
        if (seq / name).is_file():
            return seq / name
    return None


def calibrated_lens(calibration: Path, width: int, height: int) -> LensFit:
    """The fisheye fitted to the calibration at the frames' size (fitted once per lens)."""
    lens = read_ocam(calibration)
    if (lens.width, lens.height) != (width, height):
        lens = lens.scaled(width, height)
    return _fit(lens.model_dump_json())


@lru_cache(maxsize=4)
def _fit(lens_json: str) -> LensFit:
    return fit_fisheye(OcamLens.model_validate_json(lens_json))


class C3VDGroundTruth(NumberedGroundTruth):
    """Depth tiffs and pose.txt of one C3VD sequence, indexed by source_index."""

    dataset = NAME
    kind = GT_KIND
    title = "C3VD"
    frame_pattern = COLOR
    depth_pattern = DEPTH
    decode_depth = staticmethod(decode_depth)

    def has_poses(self) -> bool:
        return (self.dir / "pose.txt").is_file()

    def poses(self) -> list[np.ndarray]:
        if not self.has_poses():
            return []
        lines = read_poses(self.dir / "pose.txt")
        if self.numbers and max(self.numbers) < len(lines):
            return [lines[n] for n in self.numbers]  # line n is frame number n
        if len(lines) == len(self.numbers):
            return lines
        raise InputError(
            f"{self.dir / 'pose.txt'} has {len(lines)} poses for {len(self.numbers)} frames "
            f"numbered up to {max(self.numbers)}"
        )

    def mesh_path(self) -> Path | None:
        """The registered model (mm, pose frame): what the mesh stage scores against."""
        return find_mesh(self.dir)


class C3VDSource(ImageListSource):
    kind = NAME
    truth = C3VDGroundTruth


def open_sequence(path: Path, intrinsics: Camera | None = None) -> C3VDSource:
    path = Path(path)
    frames = numbered(path, COLOR)
    if not frames:
        raise InputError(f"{path} is not a C3VD sequence ({LAYOUT})")
    intrinsics = intrinsics or find_intrinsics(path)
    said = None
    calibration = find_calibration(path) if intrinsics is None else None
    if calibration is not None:
        with Image.open(frames[0][1]) as image:
            fit = calibrated_lens(calibration, *image.size)
        intrinsics = fit.camera
        said = f"{fit.said()}; from {calibration}"
    has_gt = (path / "pose.txt").is_file() or bool(numbered(path, DEPTH)) or bool(find_mesh(path))
    source = C3VDSource(path, [f for _, f in frames], intrinsics, path if has_gt else None)
    if said:
        source.notes.insert(0, said)
    return source


def ground_truth(path: Path) -> C3VDGroundTruth:
    return C3VDGroundTruth(path)
