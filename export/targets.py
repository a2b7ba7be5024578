"""The tools that read EndoNeRF's layout, and what each one's loader takes (`--for`).

Each target is what its public loader does with poses_bounds.npy, images/, depth/ and masks/:
which camera axes the 3x5's rotation columns are, which image size it assumes, where it puts the
principal point, and how it turns depth into points. The export writes exactly that, with depth
and translations in one unit, so the loader's back-projection puts every frame's points on one
surface (tests/test_export_targets.py re-implements each loader's lines and checks it).

- endonerf (med-air/EndoNeRF, load_llff.py `load_llff_data(davinci_endoscopic=True)`, as its
  configs/*.txt set it): the 3x5 taken as a NeRF (OpenGL) c2w as it is; hwf's h, w replaced by the
  images' own size and f used as it is (any size); rays through (i - W/2) / f, -(j - H/2) / f, -1
  (run_endonerf_helpers.py `get_rays`): the principal point at (W/2, H/2) of pixel indices; depth
  PNGs read raw (imageio) and used in the units of the poses with `no_ndc` (with NDC, its default
  for llff data, they are divided by their range: a still camera's setting).
- endogaussian (CUHK-AIM-Group/EndoGaussian, scene/endo_loader.py `EndoNeRF_Dataset`): the 3x5
  taken as an OpenCV c2w (its OpenGL flip is commented out); img_wh = 640 x 512 hard-coded
  (downsample=1.0 in scene/dataset_readers.py), FoV from hwf's f over 640 and 512; points
  `get_pts_cam`: ((i - W/2) / f, (j - H/2) / f, 1) * depth, depth the PNG's raw value clipped to
  its 3rd..99.8th percentile; masks: 255 = excluded (`1 - mask / 255`).
- deform3dgs (jinlab-imvr/Deform3DGS, scene/endo_loader.py `EndoNeRF_Dataset`): columns 1 and 2
  negated, i.e. the 3x5 taken as an OpenGL c2w (unless the folder's path holds 'stereo_', when it
  is read as OpenCV: StereoMIS); img_wh = 640 x 512, K's principal point at hwf's (W//2, H//2);
  depth raw, points `get_pts_cam` with K, those outside the 3rd..99.8th percentile dropped.

The two Gaussian-splatting loaders render through the 3DGS rasteriser, whose centred frustum puts
the principal point at the image's centre, ((W - 1) / 2, (H - 1) / 2) in pixel centres: that is
where we put it (their point initialisation's W/2 is half a pixel off it, by their own code).
"""

from __future__ import annotations

from dataclasses import dataclass, field

#: Where a loader puts the principal point: "half" = (W/2, H/2) of pixel indices (NeRF's
#: get_rays), "centre" = ((W - 1) / 2, (H - 1) / 2), the image's centre (3DGS's rasteriser).
PRINCIPAL = ("half", "centre")


@dataclass(frozen=True)
class Target:
    """What one loader of EndoNeRF's layout takes."""

    name: str
    axes: str  # the rotation columns of poses_bounds.npy (stages.io.endonerf.LLFF_COLUMNS)
    size: tuple[int, int] | None  # (width, height) the loader assumes; None: the images' own
    principal: str  # one of PRINCIPAL
    loader: str  # the public code this follows: repository and file
    notes: tuple[str, ...] = field(default_factory=tuple)

    def principal_point(self, width: int, height: int) -> tuple[float, float]:
        """(cx, cy) in endopipe's pixel-centre convention for a width x height image."""
        if self.principal == "half":
            return width / 2, height / 2
        return (width - 1) / 2, (height - 1) / 2


TARGETS: dict[str, Target] = {
    "endonerf": Target(
        name="endonerf",
        axes="opengl",
        size=None,
        principal="half",
        loader="med-air/EndoNeRF load_llff.py (davinci_endoscopic=True), run_endonerf_helpers.py",
        notes=(
            "EndoNeRF: keep davinci_endoscopic=True (its configs' setting: the poses as they are); "
            "a moving camera needs no_ndc=True (NDC assumes one forward-looking view)",
        ),
    ),
    "endogaussian": Target(
        name="endogaussian",
        axes="opencv",
        size=(640, 512),
        principal="centre",
        loader="CUHK-AIM-Group/EndoGaussian scene/endo_loader.py (EndoNeRF_Dataset)",
        notes=("EndoGaussian: read with its endonerf loader (mode binocular: depth/ as given)",),
    ),
    "deform3dgs": Target(
        name="deform3dgs",
        axes="opengl",
        size=(640, 512),
        principal="centre",
        loader="jinlab-imvr/Deform3DGS scene/endo_loader.py (EndoNeRF_Dataset)",
        notes=(
            "Deform3DGS: keep 'stereo_' out of the folder's path (its loader then reads the poses "
            "as OpenCV and the masks as StereoMIS's)",
        ),
    ),
}
