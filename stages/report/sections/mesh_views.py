"""The mesh on the page: the interactive three.js viewer and static renderings of 06_mesh's
mesh, decimated to the page's face budget."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from endopipe.stages.report.images import gif_uri, image_uri
from endopipe.stages.report.kit import one_line
from endopipe.stages.report.load import CaseData
from endopipe.stages.report.mesh3d import (
    decimate,
    mesh_viewer_page,
    principal_axes,
    render_mesh_view,
    shown_colours,
    view_framing,
)
from endopipe.stages.report.sections.common import Figure, ReportInfo

VIEWER_NOTE = (
    "Interactive: drag to rotate, scroll to zoom, right-drag to pan. three.js is inlined "
    "(bundled with trimesh), so this works offline; it needs WebGL. Blue line: camera path."
)


@dataclass
class MeshViews:
    """What the 3D view part shows. `problem`: why there is no mesh to show at all."""

    problem: str | None = None
    faces: str = ""  # "N faces, shown decimated to M"
    viewer: str | None = None  # the viewer's page, for an iframe
    viewer_problem: str | None = None
    views: list[Figure] = field(default_factory=list)
    #: a scene that moves: its surface at each chosen time (06_mesh/times/), then all of them
    #: looping
    times: list[Figure] = field(default_factory=list)
    moving: Figure | None = None


def mesh_views(data: CaseData, info: ReportInfo) -> MeshViews:
    """The viewer and the static views; sets `info.mesh_viewer` to what the page got."""
    cfg = data.cfg
    if not data.mesh.mesh_path.is_file():
        info.mesh_viewer = "none"
        return MeshViews(problem="06_mesh/mesh.ply is missing")
    try:
        raw = data.mesh.load()
        if len(raw.faces) == 0:
            raise ValueError("mesh.ply holds no triangles")
        colours = shown_colours(raw.colours, len(raw.vertices))
        v, f, c = decimate(raw.vertices, raw.faces, cfg.mesh_max_faces, colours)
    except Exception as e:  # noqa: BLE001
        return MeshViews(problem=f"mesh.ply unreadable: {one_line(e)}")
    n_orig = len(raw.faces)
    shown = MeshViews(
        faces=f"{n_orig:,} faces, shown decimated to {len(f):,}"
        if len(f) < n_orig
        else f"{n_orig:,} faces"
    )
    info.mesh_viewer = "static"
    if cfg.include_mesh_viewer:
        path_points = data.poses.centres() if data.poses is not None else None
        try:
            shown.viewer = mesh_viewer_page(v, f, c, path_points)
            info.mesh_viewer = "three.js (inlined from trimesh)"
        except Exception as e:  # noqa: BLE001 - fall back to the static views
            shown.viewer_problem = f"interactive viewer: {one_line(e)}; static views below instead"
    axes = principal_axes(v)
    if cfg.mesh_views:
        defs = [
            ("side", axes[0], axes[1]),
            ("top", axes[0], axes[2]),
            ("end-on (along the lumen)", axes[1], axes[2]),
        ][: cfg.mesh_views]
        for label, right, up in defs:
            img = render_mesh_view(v, f, c, right, up)
            shown.views.append(Figure(image_uri(img, "jpg", cfg.jpeg_quality), label))
    time_views(data, shown, axes)
    return shown


def time_views(data: CaseData, shown: MeshViews, axes: np.ndarray) -> None:
    """A scene that moves: each time's surface along mesh.ply's first two principal axes,
    framed alike and without colour (the relief is what moves), as stills and as a loop."""
    try:
        meshes = {f: data.mesh.load_time(f) for f in data.mesh.time_meshes}
    except Exception as e:  # noqa: BLE001 - the main views stand without them
        shown.times = [Figure("", f"06_mesh/times/ unreadable: {one_line(e)}")]
        return
    meshes = {f: m for f, m in meshes.items() if len(m.faces)}
    if len(meshes) < 2:
        return
    right, up = axes[0], axes[1]
    every = np.concatenate([np.asarray(m.vertices) for m in meshes.values()])
    framing = view_framing(every, right, up)
    cfg = data.cfg
    images = []
    for frame, mesh in meshes.items():
        v, f, _ = decimate(mesh.vertices, mesh.faces, cfg.mesh_max_faces)
        img = render_mesh_view(v, f, None, right, up, width=300, framing=framing)
        images.append(img)
        shown.times.append(Figure(image_uri(img, "jpg", cfg.jpeg_quality), f"frame {frame}"))
    frames = ", ".join(map(str, meshes))
    shown.moving = Figure(gif_uri(images), f"frames {frames}, looping")
