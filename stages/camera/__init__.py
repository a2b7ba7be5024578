"""The camera library: one camera type with its lens, one projection, one ray generator, poses.

`model.Camera` (intrinsics + distortion), `projection` (points -> pixels, the lens model),
`rays` (pixels -> rays -> points, numpy or torch), `transforms` (c2w poses, sim3 alignment,
rotations through scipy). Everything that makes a ray or projects a point goes through here.
"""

from endopipe.stages.camera.model import Camera
from endopipe.stages.camera.projection import (
    distort_normalised,
    pixel_grid,
    project,
    project_camera,
    undistort_normalised,
    world_to_camera,
)
from endopipe.stages.camera.rays import (
    backproject,
    camera_rays,
    direction_table,
    image_directions,
    lens_valid_mask,
    pixel_directions,
    pixel_rays,
    rays_from_directions,
)
from endopipe.stages.camera.transforms import (
    apply_sim3,
    look_at,
    matrix_to_quat_wxyz,
    quat_wxyz_to_matrix,
    rotation_angle_deg,
    umeyama,
)

__all__ = [
    "Camera",
    "apply_sim3",
    "backproject",
    "camera_rays",
    "direction_table",
    "distort_normalised",
    "image_directions",
    "lens_valid_mask",
    "look_at",
    "matrix_to_quat_wxyz",
    "pixel_directions",
    "pixel_grid",
    "pixel_rays",
    "project",
    "project_camera",
    "quat_wxyz_to_matrix",
    "rays_from_directions",
    "rotation_angle_deg",
    "umeyama",
    "undistort_normalised",
    "world_to_camera",
]
