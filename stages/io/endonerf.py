"""EndoNeRF's layout (EndoNeRF, EndoGaussian, Deform3DGS, SurgicalGaussian), read in place.

```
cutting_tissues_twice/
  images/frame-000000.color.png ...   RGB frames (any PNG/JPG names; sorted by their number)
  masks/frame-000000.mask.png ...     optional: 255 = tool (excluded), 0 = tissue
  depth/frame-000000.depth.png ...    optional: depth from stereo, in the PNG's own units
  poses_bounds.npy                    LLFF: one row of 17 a frame, [R | t | hwf] (3x5) + near, far
  endonerf.json                       optional (endopipe's export and synth): axes, depth_scale
```

Masks and depth belong to the frame whose file carries the same number. The intrinsics are
LLFF's: one focal length (hwf's f, scaled when the images are not h x w), the principal point at
the image centre, no lens.

The poses are the data set's own, not a measurement: EndoNeRF's clips give every frame the same
identity pose (the scope is held still). They are exposed as the input's `known_poses` and
never as ground truth, so nothing is scored against them (no ATE on a made-up path). Their
rotation columns are read as a NeRF c2w (right, up, back: EndoNeRF's `davinci_endoscopic`
loader) unless `endonerf.json` names other axes. The depth comes from stereo matching: ground
truth of kind `pseudo`, as Hamlyn's, and it also supervises (`attach_depth`): as metric depth
when `endonerf.json` says millimetres, else as a relative depth prior (a score against the same
maps is then no independent check, and the depth stage says so). A synthetic case written in
this layout keeps its exact `gt/` beside it, which is read instead.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from PIL import Image

from endopipe.pipeline.cache import digest_path, digest_text
from endopipe.pipeline.errors import InputError
from endopipe.stages.camera import Camera
from endopipe.stages.io.depth_prior import DepthPrior
from endopipe.stages.io.frame_truth import PerFrameGroundTruth
from endopipe.stages.io.given_depth import GivenDepth
from endopipe.stages.io.ground_truth import (
    GroundTruthSource,
    holds_case_truth,
    open_case_truth,
)
from endopipe.stages.io.images import ImageListSource, list_images
from endopipe.stages.io.name_numbers import file_number
from endopipe.stages.io.tool_masks import masks_for_frames, numbered_masks

NAME = "endonerf"
LAYOUT = "images/*.png, poses_bounds.npy (LLFF), optional masks/ (255 = tool) and depth/"
GT_KIND = "pseudo"
POSES_FILE = "poses_bounds.npy"
META_FILE = "endonerf.json"

ENDONERF_AXES = ("llff", "opengl", "opencv")
#: For each `axes` choice: which OpenCV camera axis (0 = x, 1 = y, 2 = z) and sign fill the
#: three rotation columns of an LLFF 3x5 matrix.
LLFF_COLUMNS: dict[str, tuple[tuple[int, float], ...]] = {
    "llff": ((1, 1.0), (0, 1.0), (2, -1.0)),  # down, right, back
    "opengl": ((0, 1.0), (1, -1.0), (2, -1.0)),  # right, up, back
    "opencv": ((0, 1.0), (1, 1.0), (2, 1.0)),  # right, down, forward
}
#: EndoNeRF's own loader for its da Vinci clips takes the 3x5 as a NeRF (OpenGL) c2w.
DEFAULT_AXES = "opengl"


def c2w_from_llff(m: np.ndarray, axes: str = "llff") -> np.ndarray:
    """LLFF's 3x5 (rotation columns in the order of `axes`) back to an OpenCV c2w."""
    c2w = np.eye(4)
    for col, (axis, sign) in enumerate(LLFF_COLUMNS[axes]):
        c2w[:3, axis] = sign * m[:, col]
    c2w[:3, 3] = m[:, 3]
    return c2w


def is_sequence(path: Path) -> bool:
    path = Path(path)
    return (
        (path / POSES_FILE).is_file()
        and (path / "images").is_dir()
        and bool(list_images(path / "images"))
    )


def frame_files(path: Path) -> list[Path]:
    """images/ in the order of the numbers in their names (names without one last)."""
    files = list_images(Path(path) / "images")
    return sorted(files, key=lambda f: (file_number(f) is None, file_number(f) or 0, f.name))


def read_poses_bounds(path: Path) -> np.ndarray:
    """poses_bounds.npy as (N, 17) float64; one InputError line when it is not that."""
    file = Path(path) / POSES_FILE
    try:
        arr = np.asarray(np.load(file), dtype=np.float64)
    except (OSError, ValueError) as e:
        raise InputError(f"cannot read {file}: {e}") from None
    if arr.ndim != 2 or arr.shape[1] != 17 or not len(arr) or not np.isfinite(arr).all():
        raise InputError(
            f"{file} holds an array of shape {arr.shape}; LLFF's poses_bounds.npy has one row "
            "of 17 finite numbers a frame (3x5 [R | t | hwf], near, far)"
        )
    return arr


def metadata(path: Path) -> dict:
    """endonerf.json (written by endopipe's export and synth), or {}."""
    file = Path(path) / META_FILE
    try:
        return json.loads(file.read_text()) if file.is_file() else {}
    except (OSError, ValueError):
        return {}


def intrinsics_from_hwf(hwf: np.ndarray, width: int, height: int) -> Camera:
    """LLFF's camera: focal f for an h x w image, principal point at the centre; scaled to
    the images' size when they are not h x w."""
    h, w, f = (float(v) for v in hwf)
    if h <= 0 or w <= 0 or f <= 0:
        raise InputError(f"{POSES_FILE}'s hwf ({h:g}, {w:g}, {f:g}) must be positive")
    if abs(w / h - width / height) > 0.01:
        raise InputError(
            f"{POSES_FILE} is for {w:g}x{h:g} images but the frames are {width}x{height}; give "
            "--intrinsics FILE for these frames"
        )
    return Camera(
        width=width,
        height=height,
        fx=f * width / w,
        fy=f * height / h,
        cx=(width - 1) / 2,
        cy=(height - 1) / 2,
    )


class EndoNeRFGroundTruth(PerFrameGroundTruth):
    """depth/ (stereo: pseudo ground truth), matched to the frames by number. Values in the
    PNG's own units, or divided by endonerf.json's `depth_scale` when it gives one."""

    dataset = NAME
    kind = GT_KIND
    title = "EndoNeRF"
    units = "png"

    def __init__(self, seq: Path) -> None:
        seq = Path(seq)
        depth = numbered_masks(seq / "depth")
        numbers = [file_number(f) for f in frame_files(seq)]
        meta = metadata(seq)
        self.scale = float(meta.get("depth_scale") or 1.0)
        if meta.get("depth_scale"):
            self.units = str(meta.get("units", "png"))
        files = [depth.get(n) if n is not None else None for n in numbers]
        super().__init__(seq, files, len(depth))

    def decode_depth(self, raw: np.ndarray) -> np.ndarray:
        return raw.astype(np.float32) / self.scale  # 0 = no stereo match


class EndoNeRFSource(ImageListSource):
    kind = NAME
    truth = None  # ground_truth() below: a synthetic case's gt/ first

    def ground_truth(self) -> GroundTruthSource | None:
        return ground_truth(self.gt_dir) if self.gt_dir is not None else None


def open_sequence(path: Path, intrinsics: Camera | None = None) -> EndoNeRFSource:
    path = Path(path)
    if not is_sequence(path):
        raise InputError(f"{path} is not an EndoNeRF folder ({LAYOUT})")
    files = frame_files(path)
    rows = read_poses_bounds(path)
    if intrinsics is None:
        with Image.open(files[0]) as image:
            width, height = image.size
        intrinsics = intrinsics_from_hwf(rows[0, :15].reshape(3, 5)[:, 4], width, height)
    has_gt = (path / "depth").is_dir() or holds_case_truth(path / "gt")
    source = EndoNeRFSource(path, files, intrinsics, path if has_gt else None)
    source.tool_masks = masks_for_frames(path / "masks", [file_number(f) for f in files])
    if (path / "depth").is_dir():
        attach_depth(source, path)
    if len(rows) == len(files):  # rows follow the frames; otherwise no frame's pose is known
        axes = str(metadata(path).get("axes", DEFAULT_AXES))
        axes = axes if axes in LLFF_COLUMNS else DEFAULT_AXES
        source.known_poses = [c2w_from_llff(r[:15].reshape(3, 5), axes) for r in rows]
        source.known_poses_from = f"{path / POSES_FILE} (the data set's own, axes {axes})"
    return source


def attach_depth(source: EndoNeRFSource, path: Path) -> None:
    """depth/ supervises: as metric depth when endonerf.json says it is millimetres (endopipe's
    export and synth), else as a relative depth prior, since EndoNeRF as released names no
    unit (its loaders scale it by hand)."""
    maps = EndoNeRFGroundTruth(path)
    files = {i: f for i in range(len(source.files)) if (f := maps.depth_file(i)) is not None}
    if not files:
        return
    identity = digest_text("|".join(f"{i}:{digest_path(f)}" for i, f in sorted(files.items())))
    if maps.units != "mm":
        source.depth_prior = DepthPrior(path / "depth", files)
        return
    # depth_scale counts a unit of the poses, which are mm x pose_scale (endopipe's --for export)
    per_mm = float(metadata(path).get("pose_scale") or 1.0)

    def depth_mm(source_index: int) -> np.ndarray | None:
        depth = maps.depth(source_index)
        return None if depth is None else depth / np.float32(per_mm)

    said = f"{path / 'depth'} (the data set's depth, mm by {META_FILE})"
    source.given_depth = GivenDepth(depth_mm, said, f"{identity}|{per_mm:g}")


def ground_truth(path: Path) -> GroundTruthSource:
    """A synthetic case's exact gt/ when it is there, else depth/ as pseudo ground truth."""
    path = Path(path)
    if holds_case_truth(path / "gt"):
        return open_case_truth(path / "gt")
    return EndoNeRFGroundTruth(path)
