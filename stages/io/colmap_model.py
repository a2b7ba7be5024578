"""COLMAP models: read and written through pycolmap, conventions converted once.

Conventions (docs/formats.md): endopipe poses are OpenCV camera-to-world (x right, y down, z
forward) and its principal points use the OpenCV pixel convention (the centre of the top-left pixel
is (0, 0)). COLMAP stores world-to-camera poses and puts that pixel centre at (0.5, 0.5), so a
COLMAP principal point is the OpenCV one + 0.5. nerfstudio's transforms.json is transforms_json.py.

There is one camera type, `Camera`: `camera_from_colmap` / `camera_to_colmap` convert it to and
from COLMAP's (model name + params), lens distortion included both ways. pycolmap is imported
inside the functions that need it: cv2 must be imported first (see `endopipe.stages`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from endopipe.pipeline.errors import InputError
from endopipe.stages.camera import Camera

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
    reconstruction: Any = None  # the pycolmap.Reconstruction read, with its tracks (a model)


def c2w_from_cam_from_world(matrix_3x4: np.ndarray) -> np.ndarray:
    """COLMAP's cam_from_world (3x4) -> a 4x4 camera-to-world pose."""
    w2c = np.eye(4)
    w2c[:3, :4] = matrix_3x4
    return np.linalg.inv(w2c)


def reconstruction_from_poses(camera: Camera, c2w: dict[str, np.ndarray], model: str | None = None):
    """A pycolmap.Reconstruction of one camera and posed images, without tracks.

    `model` is the COLMAP camera model to give the camera as (default: the smallest that holds
    its lens). Image ids follow the order of `c2w`.
    """
    import pycolmap

    name, params = camera_to_colmap(camera, model)
    rec = pycolmap.Reconstruction()
    cam = pycolmap.Camera(
        model=name, width=camera.width, height=camera.height, params=params, camera_id=1
    )
    rec.add_camera_with_trivial_rig(cam)
    for image_id, (image_name, pose) in enumerate(c2w.items(), start=1):
        image = pycolmap.Image(name=image_name, camera_id=1, image_id=image_id)
        rec.add_image_with_trivial_frame(image, cam_from_world(pose))
    return rec


def cam_from_world(c2w: np.ndarray):
    """A 4x4 camera-to-world pose as COLMAP's cam_from_world (pycolmap.Rigid3d)."""
    import pycolmap

    return pycolmap.Rigid3d(np.linalg.inv(np.asarray(c2w, dtype=np.float64))[:3])


def set_poses(rec, c2w: dict[str, np.ndarray]) -> int:
    """Move the images of `rec` named in `c2w` to those camera-to-world poses (their tracks
    stay; the points' reprojection errors are recomputed). Returns how many moved."""
    moved = 0
    for image in rec.images.values():
        pose = c2w.get(image.name)
        if pose is None or not image.has_pose:
            continue
        rec.frame(image.frame_id).rig_from_world = cam_from_world(pose)  # trivial rig
        moved += 1
    rec.update_point_3d_errors()
    return moved


def write_text_model(
    folder: Path, camera: Camera, c2w: dict[str, np.ndarray], model: str | None = None
) -> None:
    """A COLMAP text model of poses without tracks (empty points3D.txt), written by pycolmap.

    `model` is the COLMAP camera model to write the camera as (default: the smallest that holds
    its lens). Image ids follow the order of `c2w`.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    reconstruction_from_poses(camera, c2w, model).write_text(str(folder))


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
    return PoseSet(camera, poses, xyz, rgb, model, rec)


def keep_images(rec, names: dict[str, str]) -> None:
    """`rec` cut to the images named in `names` (old name -> new name), renamed: every other
    image is deregistered, so its observations leave the tracks (points left seen by fewer than
    two images are deleted by COLMAP)."""
    for image in list(rec.images.values()):
        if image.name in names:
            image.name = names[image.name]
            continue
        if image.has_pose:
            rec.deregister_frame(image.frame_id)
        image.name = f"unused-{image.image_id}"  # never one of the new names


def reconstruction_points(rec) -> tuple[np.ndarray, np.ndarray]:
    """Sparse points (Nx3 float64) and their colours (Nx3 uint8) of a pycolmap Reconstruction."""
    pts = list(rec.points3D.values())
    if not pts:
        return np.zeros((0, 3)), np.zeros((0, 3), np.uint8)
    xyz = np.array([p.xyz for p in pts], dtype=np.float64)
    rgb = np.array([p.color for p in pts], dtype=np.uint8)
    return xyz, rgb


def write_ply(path: Path, xyz: np.ndarray, rgb: np.ndarray | None = None) -> None:
    """A coloured point cloud as a binary PLY, written by trimesh (grey when `rgb` is None)."""
    import trimesh

    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    rgb = np.full((len(xyz), 3), 200, np.uint8) if rgb is None else np.asarray(rgb, np.uint8)
    trimesh.PointCloud(xyz, colors=rgb.reshape(-1, 3)).export(str(path), file_type="ply")


def _short(e: BaseException) -> str:
    text = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
    return text[:160]
