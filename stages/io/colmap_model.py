"""COLMAP models and nerfstudio's transforms.json: read and write, conventions converted once.

Conventions (DESIGN §4): endopipe poses are OpenCV camera-to-world (x right, y down, z forward)
and its principal points use the OpenCV pixel convention (the centre of the top-left pixel is
(0, 0)). COLMAP stores world-to-camera poses and puts that pixel centre at (0.5, 0.5), so a COLMAP
principal point is the OpenCV one + 0.5. nerfstudio's transforms.json uses OpenGL camera axes
(x right, y up, z backward) and, like COLMAP, pixel centres at +0.5.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from endopipe.pipeline.errors import InputError
from endopipe.stages.camera import Camera

#: c2w_opengl = c2w_opencv @ OPENGL_FROM_OPENCV (and back: the matrix is its own inverse).
OPENGL_FROM_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])

#: Where fx, fy, cx, cy sit in COLMAP's parameter vector, per camera model (fy = fx when absent).
PINHOLE_PARAMS = {
    "SIMPLE_PINHOLE": (0, 0, 1, 2),
    "PINHOLE": (0, 1, 2, 3),
    "SIMPLE_RADIAL": (0, 0, 1, 2),
    "RADIAL": (0, 0, 1, 2),
    "OPENCV": (0, 1, 2, 3),
    "FULL_OPENCV": (0, 1, 2, 3),
    "OPENCV_FISHEYE": (0, 1, 2, 3),
    "SIMPLE_RADIAL_FISHEYE": (0, 0, 1, 2),
    "RADIAL_FISHEYE": (0, 0, 1, 2),
    "THIN_PRISM_FISHEYE": (0, 1, 2, 3),
}


@dataclass
class CameraModel:
    """One COLMAP camera: model name, image size and parameters (COLMAP pixel convention)."""

    model: str
    width: int
    height: int
    params: list[float]

    def intrinsics(self) -> Camera:
        """The pinhole part, in endopipe's (OpenCV) pixel convention."""
        if self.model not in PINHOLE_PARAMS:
            raise InputError(
                f"COLMAP camera model {self.model} is not supported; use PINHOLE, SIMPLE_RADIAL, "
                "OPENCV or another perspective model"
            )
        i_fx, i_fy, i_cx, i_cy = PINHOLE_PARAMS[self.model]
        p = self.params
        return Camera(
            width=self.width,
            height=self.height,
            fx=p[i_fx],
            fy=p[i_fy],
            cx=p[i_cx] - 0.5,
            cy=p[i_cy] - 0.5,
        )

    def scaled(self, width: int, height: int) -> CameraModel:
        """The same camera at another resolution (focal lengths and principal point scale)."""
        if (width, height) == (self.width, self.height):
            return self
        sx, sy = width / self.width, height / self.height
        i_fx, i_fy, i_cx, i_cy = PINHOLE_PARAMS.get(self.model, (0, 1, 2, 3))
        p = list(self.params)
        p[i_fx] *= sx
        if i_fy != i_fx:
            p[i_fy] *= sy
        p[i_cx] *= sx  # COLMAP convention: pixel edges scale, so no half-pixel shift here
        p[i_cy] *= sy
        return CameraModel(self.model, width, height, p)

    @classmethod
    def pinhole(cls, k: Camera) -> CameraModel:
        return cls("PINHOLE", k.width, k.height, [k.fx, k.fy, k.cx + 0.5, k.cy + 0.5])

    @classmethod
    def from_intrinsics(cls, k: Camera) -> CameraModel:
        """PINHOLE, or OPENCV / FULL_OPENCV when `dist` ([k1, k2, p1, p2, k3]) is not all zero."""
        dist = [float(d) for d in (k.dist or [])]
        if not any(dist):
            return cls.pinhole(k)
        dist = (dist + [0.0] * 5)[:5]
        base = [k.fx, k.fy, k.cx + 0.5, k.cy + 0.5]
        if dist[4] == 0.0:
            return cls("OPENCV", k.width, k.height, base + dist[:4])
        return cls("FULL_OPENCV", k.width, k.height, base + dist + [0.0, 0.0, 0.0])


@dataclass
class PoseSet:
    """A camera plus camera-to-world poses (OpenCV) by image name, and optional sparse points."""

    camera: CameraModel | None
    c2w: dict[str, np.ndarray]
    xyz: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    rgb: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.uint8))


def c2w_from_cam_from_world(matrix_3x4: np.ndarray) -> np.ndarray:
    """COLMAP's cam_from_world (3x4) -> a 4x4 camera-to-world pose."""
    w2c = np.eye(4)
    w2c[:3, :4] = matrix_3x4
    return np.linalg.inv(w2c)


def rotmat_to_qvec(R: np.ndarray) -> np.ndarray:
    """Rotation matrix -> unit quaternion (w, x, y, z), w >= 0 (COLMAP's images.txt order)."""
    m = R
    t = np.trace(m)
    if t > 0:
        s = np.sqrt(t + 1.0) * 2
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif m[1, 1] > m[2, 2]:
        s = np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    q = np.array(q, dtype=np.float64)
    q /= np.linalg.norm(q)
    return -q if q[0] < 0 else q


def write_text_model(folder: Path, camera: CameraModel, c2w: dict[str, np.ndarray]) -> None:
    """A COLMAP text model (cameras.txt, images.txt, empty points3D.txt) for poses without tracks.

    Image ids follow the order of `c2w`; every image has an empty 2D-point line.
    """
    folder.mkdir(parents=True, exist_ok=True)
    params = " ".join(f"{p:.10g}" for p in camera.params)
    (folder / "cameras.txt").write_text(
        "# Camera list with one line of data per camera:\n"
        "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
        f"# Number of cameras: 1\n1 {camera.model} {camera.width} {camera.height} {params}\n"
    )
    lines = [
        "# Image list with two lines of data per image:",
        "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
        "#   POINTS2D[] as (X, Y, POINT3D_ID)",
        f"# Number of images: {len(c2w)}, mean observations per image: 0",
    ]
    for image_id, (name, pose) in enumerate(c2w.items(), start=1):
        w2c = np.linalg.inv(pose)
        q = rotmat_to_qvec(w2c[:3, :3])
        t = w2c[:3, 3]
        values = " ".join(f"{v:.17g}" for v in (*q, *t))
        lines += [f"{image_id} {values} 1 {name}", ""]
    (folder / "images.txt").write_text("\n".join(lines) + "\n")
    (folder / "points3D.txt").write_text(
        "# 3D point list with one line of data per point:\n"
        "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n"
        "# Number of points: 0, mean track length: 0\n"
    )


def read_colmap_model(folder: Path) -> PoseSet:
    """A COLMAP model folder (text or binary, or its `sparse/0` inside) as a PoseSet."""
    import pycolmap  # cv2 is already imported through the `endopipe.stages` package

    folder = Path(folder)
    for candidate in (folder, folder / "sparse" / "0", folder / "sparse", folder / "0"):
        if any((candidate / f"cameras.{ext}").is_file() for ext in ("txt", "bin")):
            folder = candidate
            break
    else:
        raise InputError(
            f"{folder} holds no COLMAP model (cameras.txt/.bin, images.txt/.bin, points3D.txt/.bin)"
        )
    try:
        rec = pycolmap.Reconstruction(str(folder))
    except Exception as e:  # pycolmap raises RuntimeError/ValueError on malformed files
        raise InputError(f"cannot read the COLMAP model in {folder}: {_short(e)}") from None
    if rec.num_cameras() != 1:
        raise InputError(
            f"the COLMAP model in {folder} has {rec.num_cameras()} cameras; endopipe needs one "
            "shared camera (re-run COLMAP with a single camera)"
        )
    cam = next(iter(rec.cameras.values()))
    camera = CameraModel(cam.model.name, cam.width, cam.height, [float(p) for p in cam.params])
    poses = {
        img.name: c2w_from_cam_from_world(img.cam_from_world().matrix())
        for img in rec.images.values()
        if img.has_pose
    }
    xyz, rgb = reconstruction_points(rec)
    return PoseSet(camera, poses, xyz, rgb)


def reconstruction_points(rec) -> tuple[np.ndarray, np.ndarray]:
    """Sparse points (Nx3 float64) and their colours (Nx3 uint8) of a pycolmap Reconstruction."""
    pts = list(rec.points3D.values())
    if not pts:
        return np.zeros((0, 3)), np.zeros((0, 3), np.uint8)
    xyz = np.array([p.xyz for p in pts], dtype=np.float64)
    rgb = np.array([p.color for p in pts], dtype=np.uint8)
    return xyz, rgb


def write_transforms_json(
    path: Path,
    camera: CameraModel,
    frames: list[tuple[str, str | None, np.ndarray]],
    extra: dict | None = None,
) -> None:
    """nerfstudio's transforms.json: `frames` is (file_path, mask_path, c2w OpenCV) per frame."""
    k = camera.intrinsics()
    data: dict = {
        "camera_model": "OPENCV",
        "fl_x": k.fx,
        "fl_y": k.fy,
        "cx": k.cx + 0.5,
        "cy": k.cy + 0.5,
        "w": camera.width,
        "h": camera.height,
        "k1": 0.0,
        "k2": 0.0,
        "p1": 0.0,
        "p2": 0.0,
    }
    if camera.model in ("SIMPLE_RADIAL", "RADIAL"):
        data["k1"] = camera.params[3]
        if camera.model == "RADIAL":
            data["k2"] = camera.params[4]
    elif camera.model in ("OPENCV", "FULL_OPENCV"):
        data.update(zip(("k1", "k2", "p1", "p2"), camera.params[4:8], strict=True))
    data.update(extra or {})
    data["frames"] = []
    for file_path, mask_path, c2w in frames:
        entry = {"file_path": file_path}
        if mask_path is not None:
            entry["mask_path"] = mask_path
        entry["transform_matrix"] = (np.asarray(c2w) @ OPENGL_FROM_OPENCV).tolist()
        data["frames"].append(entry)
    path.write_text(json.dumps(data, indent=2) + "\n")


def read_transforms_json(path: Path) -> PoseSet:
    """A nerfstudio / instant-ngp transforms.json as a PoseSet (poses converted to OpenCV)."""
    try:
        data = json.loads(Path(path).read_text())
        frames = data["frames"]
        poses = {}
        for f in frames:
            c2w = np.array(f["transform_matrix"], dtype=np.float64)
            if c2w.shape == (3, 4):
                c2w = np.vstack([c2w, [0, 0, 0, 1]])
            if c2w.shape != (4, 4):
                raise ValueError(f"transform_matrix of {f['file_path']} is not 4x4")
            poses[Path(f["file_path"]).name] = c2w @ OPENGL_FROM_OPENCV
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise InputError(
            f"cannot read {path} as transforms.json ({_short(e)}); it needs 'frames' with "
            "'file_path' and 'transform_matrix'"
        ) from None
    camera = None
    src = frames[0] if frames and "fl_x" in frames[0] else data
    if "fl_x" in src and "w" in src and "h" in src:
        fx = float(src["fl_x"])
        fy = float(src.get("fl_y", fx))
        cx = float(src.get("cx", src["w"] / 2))
        cy = float(src.get("cy", src["h"] / 2))
        camera = CameraModel("PINHOLE", int(src["w"]), int(src["h"]), [fx, fy, cx, cy])
    return PoseSet(camera, poses)


def write_ply(path: Path, xyz: np.ndarray, rgb: np.ndarray | None = None) -> None:
    """A binary little-endian PLY point cloud (x, y, z float32 and red, green, blue uint8)."""
    xyz = np.asarray(xyz, dtype=np.float32).reshape(-1, 3)
    rgb = np.full((len(xyz), 3), 200, np.uint8) if rgb is None else np.asarray(rgb, np.uint8)
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"element vertex {len(xyz)}\n"
        "property float x\nproperty float y\nproperty float z\n"
        "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n"
    )
    rec = np.empty(len(xyz), dtype=[("p", "<f4", 3), ("c", "u1", 3)])
    rec["p"], rec["c"] = xyz, rgb.reshape(-1, 3)
    path.write_bytes(header.encode() + rec.tobytes())


def trailing_number(name: str) -> int | None:
    """The last integer in a file name's stem (`frame_0012.png` -> 12), or None."""
    found = re.findall(r"\d+", Path(name).stem)
    return int(found[-1]) if found else None


def _short(e: BaseException) -> str:
    text = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
    return text[:160]
