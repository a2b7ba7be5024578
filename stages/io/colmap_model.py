"""COLMAP models and nerfstudio's transforms.json: read and write, conventions converted once.

Conventions (DESIGN §4): endopipe poses are OpenCV camera-to-world (x right, y down, z forward)
and its principal points use the OpenCV pixel convention (the centre of the top-left pixel is
(0, 0)). COLMAP stores world-to-camera poses and puts that pixel centre at (0.5, 0.5), so a COLMAP
principal point is the OpenCV one + 0.5. nerfstudio's transforms.json uses OpenGL camera axes
(x right, y up, z backward) and, like COLMAP, pixel centres at +0.5.

There is one camera type, `Camera`: `camera_from_colmap` / `camera_to_colmap` convert it to and
from COLMAP's (model name + params), lens distortion included both ways.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from endopipe.pipeline.errors import InputError
from endopipe.stages.camera import Camera, matrix_to_quat_wxyz

#: c2w_opengl = c2w_opencv @ OPENGL_FROM_OPENCV (and back: the matrix is its own inverse).
OPENGL_FROM_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])

#: COLMAP's parameter names per camera model (pycolmap's `params_info`), and the lens of
#: endopipe's `Camera` each one is: "opencv" (radial-tangential) or "fisheye" (equidistant;
#: COLMAP's fisheye models are OpenCV's fisheye with fewer coefficients).
COLMAP_MODELS: dict[str, tuple[str, tuple[str, ...]]] = {
    "SIMPLE_PINHOLE": ("pinhole", ("f", "cx", "cy")),
    "PINHOLE": ("pinhole", ("fx", "fy", "cx", "cy")),
    "SIMPLE_RADIAL": ("opencv", ("f", "cx", "cy", "k1")),
    "RADIAL": ("opencv", ("f", "cx", "cy", "k1", "k2")),
    "OPENCV": ("opencv", ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2")),
    "FULL_OPENCV": (
        "opencv",
        ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"),
    ),
    "SIMPLE_RADIAL_FISHEYE": ("fisheye", ("f", "cx", "cy", "k1")),
    "RADIAL_FISHEYE": ("fisheye", ("f", "cx", "cy", "k1", "k2")),
    "OPENCV_FISHEYE": ("fisheye", ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4")),
}
#: The coefficients of each lens of `Camera.dist`, in order.
LENS_COEFFICIENTS = {"opencv": ("k1", "k2", "p1", "p2", "k3"), "fisheye": ("k1", "k2", "k3", "k4")}


def camera_from_colmap(model: str, width: int, height: int, params: list[float]) -> Camera:
    """A COLMAP camera (model name + params, COLMAP pixel convention) as endopipe's `Camera`,
    its lens distortion included."""
    if model not in COLMAP_MODELS:
        raise InputError(
            f"COLMAP camera model {model} is not supported; use one of {', '.join(COLMAP_MODELS)}"
        )
    lens, names = COLMAP_MODELS[model]
    if len(params) != len(names):
        raise InputError(f"a COLMAP {model} camera has {len(names)} params, not {len(params)}")
    v = dict(zip(names, map(float, params), strict=True))
    if any(v.get(k, 0.0) for k in ("k4", "k5", "k6")) and lens == "opencv":
        raise InputError("FULL_OPENCV's rational terms (k4, k5, k6) are not supported")
    fx = v.get("fx", v.get("f"))
    fy = v.get("fy", v.get("f"))
    dist = None
    if lens != "pinhole":
        coefficients = LENS_COEFFICIENTS[lens]
        if lens == "opencv" and "k3" not in v:
            coefficients = coefficients[:4]
        dist = [v.get(k, 0.0) for k in coefficients]
    return Camera(
        width=width,
        height=height,
        fx=fx,
        fy=fy,
        cx=v["cx"] - 0.5,
        cy=v["cy"] - 0.5,
        model=lens,
        dist=dist,
    )


def default_colmap_model(camera: Camera) -> str:
    """The smallest COLMAP model that holds the camera: PINHOLE, OPENCV, FULL_OPENCV (k3) or
    OPENCV_FISHEYE."""
    if not camera.distorted:
        return "PINHOLE"
    if camera.model == "fisheye":
        return "OPENCV_FISHEYE"
    dist = list(camera.dist or [])
    return "FULL_OPENCV" if len(dist) > 4 and dist[4] != 0.0 else "OPENCV"


def camera_to_colmap(camera: Camera, model: str | None = None) -> tuple[str, list[float]]:
    """endopipe's `Camera` as a COLMAP camera: model name and params (principal point + 0.5).
    `model` picks the COLMAP model (default: `default_colmap_model`); a ValueError says when the
    camera does not fit it (two focal lengths in a one-focal model, a coefficient it lacks)."""
    model = model or default_colmap_model(camera)
    if model not in COLMAP_MODELS:
        raise ValueError(f"COLMAP camera model {model} is not supported")
    lens, names = COLMAP_MODELS[model]
    coefficients: dict[str, float] = {}
    if camera.distorted:
        coefficients = dict(zip(LENS_COEFFICIENTS[camera.model], camera.dist or [], strict=False))
        if lens != camera.model:
            raise ValueError(f"a {camera.model} lens is not a COLMAP {model} camera")
    lost = [k for k, c in coefficients.items() if c != 0.0 and k not in names]
    if lost:
        raise ValueError(f"a COLMAP {model} camera has no {', '.join(lost)}")
    if "f" in names and camera.fx != camera.fy:
        raise ValueError(f"a COLMAP {model} camera has one focal length; fx != fy")
    values = {"f": camera.fx, "fx": camera.fx, "fy": camera.fy}
    values |= {"cx": camera.cx + 0.5, "cy": camera.cy + 0.5, **coefficients}
    return model, [float(values.get(n, 0.0)) for n in names]


def camera_from_pycolmap(camera) -> tuple[Camera, str]:
    """A pycolmap.Camera as endopipe's `Camera` and its COLMAP model name."""
    name = camera.model.name
    return camera_from_colmap(name, camera.width, camera.height, list(camera.params)), name


@dataclass
class PoseSet:
    """A camera plus camera-to-world poses (OpenCV) by image name, and optional sparse points."""

    camera: Camera | None
    c2w: dict[str, np.ndarray]
    xyz: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    rgb: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.uint8))
    colmap_model: str | None = None  # the COLMAP model the camera came as (None: none given)


def c2w_from_cam_from_world(matrix_3x4: np.ndarray) -> np.ndarray:
    """COLMAP's cam_from_world (3x4) -> a 4x4 camera-to-world pose."""
    w2c = np.eye(4)
    w2c[:3, :4] = matrix_3x4
    return np.linalg.inv(w2c)


def write_text_model(
    folder: Path, camera: Camera, c2w: dict[str, np.ndarray], model: str | None = None
) -> None:
    """A COLMAP text model (cameras.txt, images.txt, empty points3D.txt) for poses without tracks.

    `model` is the COLMAP camera model to write the camera as (default: the smallest that holds
    its lens). Image ids follow the order of `c2w`; every image has an empty 2D-point line.
    """
    folder.mkdir(parents=True, exist_ok=True)
    name, values = camera_to_colmap(camera, model)
    params = " ".join(f"{p:.10g}" for p in values)
    (folder / "cameras.txt").write_text(
        "# Camera list with one line of data per camera:\n"
        "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
        f"# Number of cameras: 1\n1 {name} {camera.width} {camera.height} {params}\n"
    )
    lines = [
        "# Image list with two lines of data per image:",
        "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
        "#   POINTS2D[] as (X, Y, POINT3D_ID)",
        f"# Number of images: {len(c2w)}, mean observations per image: 0",
    ]
    for image_id, (name, pose) in enumerate(c2w.items(), start=1):
        w2c = np.linalg.inv(pose)
        q = matrix_to_quat_wxyz(w2c[:3, :3])
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
    camera, model = camera_from_pycolmap(next(iter(rec.cameras.values())))
    poses = {
        img.name: c2w_from_cam_from_world(img.cam_from_world().matrix())
        for img in rec.images.values()
        if img.has_pose
    }
    xyz, rgb = reconstruction_points(rec)
    return PoseSet(camera, poses, xyz, rgb, model)


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
    camera: Camera,
    frames: list[tuple[str, str | None, np.ndarray]],
    extra: dict | None = None,
) -> None:
    """nerfstudio's transforms.json: `frames` is (file_path, mask_path, c2w OpenCV) per frame.
    The lens is nerfstudio's OPENCV (k1, k2, p1, p2, and k3 when set) or OPENCV_FISHEYE."""
    fisheye = camera.distorted and camera.model == "fisheye"
    data: dict = {
        "camera_model": "OPENCV_FISHEYE" if fisheye else "OPENCV",
        "fl_x": camera.fx,
        "fl_y": camera.fy,
        "cx": camera.cx + 0.5,
        "cy": camera.cy + 0.5,
        "w": camera.width,
        "h": camera.height,
    }
    names = LENS_COEFFICIENTS["fisheye"] if fisheye else ("k1", "k2", "p1", "p2")
    data |= dict.fromkeys(names, 0.0)
    if camera.distorted:
        coefficients = dict(zip(LENS_COEFFICIENTS[camera.model], camera.dist or [], strict=False))
        data |= {k: float(c) for k, c in coefficients.items() if k in names or c != 0.0}
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
        lens = "fisheye" if src.get("camera_model") == "OPENCV_FISHEYE" else "opencv"
        dist = [float(src.get(k, 0.0)) for k in LENS_COEFFICIENTS[lens]]
        camera = Camera(
            width=int(src["w"]),
            height=int(src["h"]),
            fx=fx,
            fy=float(src.get("fl_y", fx)),
            cx=float(src.get("cx", src["w"] / 2)) - 0.5,
            cy=float(src.get("cy", src["h"] / 2)) - 0.5,
            model=lens if any(dist) else "pinhole",
            dist=dist if any(dist) else None,
        )
        return PoseSet(camera, poses, colmap_model=camera_to_colmap(camera)[0])
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
