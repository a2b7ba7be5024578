"""The surface library: triangle meshes from depth maps or a density field, cleaned, measured.

One job per module, explicit parameters (no stage configs, no stage folders):
`mesh` (RawMesh and its files), `raycast` (open3d's RaycastingScene: rays, point-to-surface),
`tsdf` (fusion of z-depth maps), `marching` (a density's iso-surface in the prior's band),
`clean` (unseen faces, floaters, smoothing), `evaluate` (Chamfer, F-score, the crop). Every
projection and pixel ray goes through stages/camera.
"""

from endopipe.stages.surface.clean import clean_mesh, cull_unseen, drop_small_components
from endopipe.stages.surface.evaluate import chamfer, evaluate_mesh, sample_surface
from endopipe.stages.surface.marching import (
    BandGrid,
    band_density_grid,
    density_mesh,
    field_density_fn,
    iso_level,
    marching_cubes_mesh,
)
from endopipe.stages.surface.mesh import RawMesh, read_mesh, write_mesh
from endopipe.stages.surface.raycast import Raycaster, point_to_surface, raycasting_scene
from endopipe.stages.surface.tsdf import DepthFrame, tsdf_fuse

__all__ = [
    "BandGrid",
    "DepthFrame",
    "RawMesh",
    "Raycaster",
    "band_density_grid",
    "chamfer",
    "clean_mesh",
    "cull_unseen",
    "density_mesh",
    "drop_small_components",
    "evaluate_mesh",
    "field_density_fn",
    "iso_level",
    "marching_cubes_mesh",
    "point_to_surface",
    "raycasting_scene",
    "read_mesh",
    "sample_surface",
    "tsdf_fuse",
    "write_mesh",
]
