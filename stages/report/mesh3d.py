"""The mesh on the page: decimated for size, static renderings, and the three.js viewer."""

from __future__ import annotations

import re

import cv2
import numpy as np

from endopipe.stages.report.kit import render

TISSUE_RGB = (214, 146, 138)


def decimate(
    vertices: np.ndarray, faces: np.ndarray, max_faces: int, colors: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """At most `max_faces` faces by quadric error decimation (fast-simplification: 0.6 s for
    the bench colon's 470k faces, where open3d's took 5.2 s); each kept vertex takes the colour
    of the nearest original one. A mesh already under the budget comes back as it is."""
    import fast_simplification
    from scipy.spatial import cKDTree

    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    if len(f) <= max_faces:
        return v, f, colors
    nv, nf = fast_simplification.simplify(
        v.astype(np.float32), f.astype(np.int32), target_count=max_faces
    )
    nv, nf = np.asarray(nv, np.float64), np.asarray(nf, np.int64)
    used = np.unique(nf)  # drop vertices no face kept
    remap = np.full(len(nv), -1, np.int64)
    remap[used] = np.arange(len(used))
    nv, nf = nv[used], remap[nf]
    nc = None
    if colors is not None:
        _, nearest = cKDTree(v).query(nv)
        nc = np.asarray(colors)[nearest]
    return nv, nf, nc


def shown_colours(colours: np.ndarray | None, n_vertices: int) -> np.ndarray | None:
    """Vertex colours worth showing: None when absent or one flat colour (then: tissue tone)."""
    if colours is None or len(colours) != n_vertices or len(colours) == 0:
        return None
    c = np.asarray(colours)[:, :3].astype(np.uint8)
    return None if np.all(c == c[0]) else c


def principal_axes(vertices: np.ndarray) -> np.ndarray:
    """Rows: the main, second and third axes of the vertex cloud (right-handed)."""
    sample = vertices[:: max(1, len(vertices) // 20000)]
    _, _, vt = np.linalg.svd(sample - sample.mean(0), full_matrices=False)
    axes = np.eye(3) if vt.shape[0] < 3 else vt.copy()
    axes[2] = np.cross(axes[0], axes[1])
    return axes


def view_framing(
    vertices: np.ndarray, right: np.ndarray, up: np.ndarray
) -> tuple[float, float, float, float]:
    """The centre and extent (x, y, width, height) of vertices seen along right x up."""
    x, y = vertices @ right, -(vertices @ up)
    return (
        float(x.max() + x.min()) / 2,
        float(y.max() + y.min()) / 2,
        float(np.ptp(x)),
        float(np.ptp(y)),
    )


def render_mesh_view(
    vertices: np.ndarray,
    faces: np.ndarray,
    colors: np.ndarray | None,
    right: np.ndarray,
    up: np.ndarray,
    width: int = 460,
    supersample: int = 2,
    framing: tuple[float, float, float, float] | None = None,
) -> np.ndarray:
    """An orthographic, two-sided rendering (painter's algorithm with OpenCV): a head light
    plus a key light from the upper left. The height follows the mesh's extent (clamped), or
    `framing` (`view_framing`'s, so that several meshes share one).

    Hand-written on purpose: no installed library renders headless here. open3d's
    OffscreenRenderer needs Vulkan or EGL with a GPU ("Failed to load vulkan library"),
    trimesh's Scene.save_image needs a pyglet window, pyrender is not installed."""
    fwd = np.cross(right, -up)  # camera looks along fwd, image x = right, image y = -up
    x, y, z = vertices @ right, -(vertices @ up), vertices @ fwd
    cx, cy, ex, ey = framing if framing is not None else view_framing(vertices, right, up)
    x, y = x - cx, y - cy
    ex, ey = max(ex, 1e-12), max(ey, 1e-12)
    height = int(np.clip(width * ey / ex, 0.3 * width, 0.9 * width))
    w, h = width * supersample, height * supersample
    s = 0.9 * min(w / ex, h / ey)
    px = np.stack([x * s + w / 2, y * s + h / 2], 1)
    tri = vertices[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-20)
    key = -fwd + 0.6 * up - 0.5 * right
    key /= np.linalg.norm(key)
    shade = 0.22 + 0.5 * np.abs(n @ fwd) + 0.35 * np.abs(n @ key)
    base = (
        colors[faces].mean(1) if colors is not None else np.tile(TISSUE_RGB, (len(faces), 1))
    ).astype(np.float64)
    rgb = np.clip(base * shade[:, None], 0, 255).astype(np.uint8)
    order = np.argsort(-z[faces].mean(1))  # far first
    img = np.full((h, w, 3), 250, np.uint8)
    pts = np.round(px[faces] * 4).astype(np.int32)  # 2 fractional bits
    for i in order:
        cv2.fillConvexPoly(img, pts[i], rgb[i].tolist(), lineType=cv2.LINE_AA, shift=2)
    return cv2.resize(img, (width, height), interpolation=cv2.INTER_AREA)


def mesh_viewer_page(
    vertices: np.ndarray,
    faces: np.ndarray,
    colors: np.ndarray | None,
    path_points: np.ndarray | None = None,
) -> str:
    """trimesh's self-contained three.js page for the mesh (double-sided, oblique initial view)
    and the camera path. Raises when the page would need the network."""
    import trimesh
    from trimesh.scene.cameras import look_at
    from trimesh.viewer.notebook import scene_to_html

    nv = len(vertices)
    rgb = np.asarray(colors if colors is not None else np.tile(TISSUE_RGB, (nv, 1)), np.uint8)
    mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=False)
    # A matte, double-sided material (glTF's default is metallic: black without an environment
    # map; a lumen is seen from inside and outside); colours as a vertex attribute.
    material = trimesh.visual.material.PBRMaterial(
        baseColorFactor=[255, 255, 255, 255],
        metallicFactor=0.0,
        roughnessFactor=0.85,
        doubleSided=True,
    )
    mesh.visual = trimesh.visual.TextureVisuals(material=material)
    mesh.visual.vertex_attributes["color"] = np.column_stack([rgb, np.full(nv, 255, np.uint8)])
    _ = mesh.vertex_normals  # cached normals are exported: smooth shading
    scene = trimesh.Scene(mesh)
    if path_points is not None and len(path_points) >= 2:
        try:
            path = trimesh.load_path(np.asarray(path_points, np.float64))
            path.colors = np.tile([31, 78, 121, 255], (len(path.entities), 1))
            scene.add_geometry(path)
        except Exception:  # noqa: BLE001 - the path is decoration
            pass
    axes = principal_axes(vertices)
    back = 0.7 * axes[1] + 0.45 * axes[0] + 0.6 * axes[2]  # from the centre towards the eye
    back /= np.linalg.norm(back)
    right = np.cross(axes[2], back)
    right /= np.linalg.norm(right)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2] = right, np.cross(back, right), back
    scene.camera_transform = look_at(vertices, scene.camera.fov, rotation=pose)
    page = scene_to_html(scene)
    if not page_is_self_contained(page):
        raise RuntimeError("trimesh's viewer page loads scripts from the network")
    # Without WebGL, three.js throws in init(): say so instead of leaving a blank frame.
    return page.replace("init();</script>", str(render("viewer_no_webgl.html.j2")), 1)


_NETWORK_LOADS = (
    re.compile(r"<script[^>]+\bsrc\s*=", re.I),
    re.compile(r"<link[^>]+\bhref\s*=\s*[\"']?(https?:)?//", re.I),
    re.compile(r"\bimport\s*(\(|[^;]*?\bfrom\s*)[\"'](https?:)?//", re.I),
    re.compile(r"\bsrc\s*=\s*[\"'](https?:)?//", re.I),
)


def page_is_self_contained(page: str) -> bool:
    """True when an HTML page loads no script, style or image from elsewhere."""
    return not any(p.search(page) for p in _NETWORK_LOADS)
