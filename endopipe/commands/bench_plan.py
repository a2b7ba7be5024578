"""What `endopipe bench` runs: the table's cases (fixed-seed synthetic inputs, some in a data
set's own layout) and variants (ablations as --set overrides), and the sweeps' cases; the plan
is checked, and narrowed to the names asked for, before any work."""

from __future__ import annotations

from pydantic import BaseModel

from endopipe.pipeline.errors import ConfigError

#: name -> --set overrides. "plain" is a NeRF without the prior, the near-light model and the
#: depth regularisers (and without the SfM-point depth): the paper's NeRF-endo baseline.
VARIANTS: dict[str, list[str]] = {
    "full": [],
    "no_prior": ["nerf.loss.prior=false"],
    "no_smooth": ["nerf.loss.smooth=false"],
    "no_geo": ["nerf.loss.geo=false"],
    "no_sparse": ["nerf.loss.sparse_weight=0"],
    "plain": [
        "nerf.loss.prior=false",
        "nerf.loss.smooth=false",
        "nerf.loss.geo=false",
        "nerf.loss.sparse_weight=0",
        "nerf.shading.enabled=false",
        "nerf.sampling.bounds=box",
    ],
}


class BenchCase(BaseModel):
    name: str
    shape: str
    frames: int
    width: int
    height: int
    seed: int
    lens: str = "pinhole"  # synth --lens
    fov_diag: float | None = None  # synth --fov-diag
    given_lens: bool = True  # False: intrinsics.json withheld, COLMAP estimates the camera
    texture_contrast: float = 1.0  # synth --texture-contrast
    vignetting: float = 0.0  # synth --vignetting
    deform: str = "none"  # synth --deform
    still_camera: bool = False  # synth --still-camera
    layout: str = "endopipe"  # synth --layout: a data set's own layout, read by its reader
    stereo: bool = False  # synth --stereo: a right eye too (hamlyn, scared)
    sets: list[str] = []  # applied to this case's runs (e.g. the COLMAP camera model)


class BenchPlan(BaseModel):
    cases: list[BenchCase]
    variants: list[str]
    sets: list[str]  # applied to every run (e.g. shorter training in --quick)
    until: str | None = None  # the last stage each run goes to (None: the whole DAG)


#: `--sweep` name -> what it measures.
SWEEPS = {"poses": "the poses stage alone on cases that vary shape, seed, texture and optics"}


def plan(
    quick: bool,
    cases: list[str] | None = None,
    variants: list[str] | None = None,
    sweep: str | None = None,
) -> BenchPlan:
    """The bench's cases and variants; `cases` / `variants` keep only those names (a rerun of
    one row after a change need not pay for the whole table). `sweep` replaces the table's
    cases by a sweep's (one run each, up to that stage)."""
    if sweep is not None:
        full = _sweep_plan(sweep, quick, variants)
    else:
        full = _plan(quick)
        if not cases:  # the lens cases run when named (--case colon_barrel ...)
            full.cases = [c for c in full.cases if c.name in DEFAULT_CASES or quick]
    if cases:
        unknown = sorted(set(cases) - {c.name for c in full.cases})
        if unknown:
            names = ", ".join(c.name for c in full.cases)
            raise ConfigError(f"unknown bench case {', '.join(unknown)}; cases: {names}")
        full.cases = [c for c in full.cases if c.name in cases]
    if variants:
        unknown = sorted(set(variants) - set(full.variants))
        if unknown:
            names = ", ".join(full.variants)
            raise ConfigError(f"unknown bench variant {', '.join(unknown)}; variants: {names}")
        full.variants = [v for v in full.variants if v in variants]
    return full


COLON = {"shape": "colon", "frames": 60, "width": 320, "height": 256, "seed": 7}
#: a still camera on the cavity's wall pulled by a tool in view
PULL_STILL = {
    "shape": "cavity",
    "frames": 120,
    "width": 320,
    "height": 256,
    "seed": 7,
    "deform": "pull",
    "still_camera": True,
}
DEFAULT_CASES = ("colon", "cavity")
SWEEP_SIZE = {"frames": 60, "width": 320, "height": 256}

#: The pose sweep: colon and cavity, several seeds, texture contrast 1 / 0.75 / 0.5 / 0.3,
#: vignetting, a wide barrel lens (given). The two seed-7 cases are the bench's colon and cavity.
POSE_SWEEP = [
    BenchCase(**SWEEP_SIZE, name="colon_s7", shape="colon", seed=7),
    BenchCase(**SWEEP_SIZE, name="cavity_s7", shape="cavity", seed=7),
    BenchCase(**SWEEP_SIZE, name="colon_s3_c0.75", shape="colon", seed=3, texture_contrast=0.75),
    BenchCase(**SWEEP_SIZE, name="cavity_s3_c0.75", shape="cavity", seed=3, texture_contrast=0.75),
    BenchCase(**SWEEP_SIZE, name="colon_s11_c0.5", shape="colon", seed=11, texture_contrast=0.5),
    BenchCase(**SWEEP_SIZE, name="cavity_s11_c0.5", shape="cavity", seed=11, texture_contrast=0.5),
    BenchCase(**SWEEP_SIZE, name="cavity_s5_v0.4", shape="cavity", seed=5, vignetting=0.4),
    BenchCase(**SWEEP_SIZE, name="colon_s5_barrel", shape="colon", seed=5, lens="barrel"),
    # nearly textureless: where the two mappers start to part
    BenchCase(**SWEEP_SIZE, name="colon_s13_c0.3", shape="colon", seed=13, texture_contrast=0.3),
    BenchCase(**SWEEP_SIZE, name="cavity_s13_c0.3", shape="cavity", seed=13, texture_contrast=0.3),
]


def _sweep_plan(sweep: str, quick: bool, variants: list[str] | None) -> BenchPlan:
    if sweep not in SWEEPS:
        raise ConfigError(f"unknown sweep {sweep}; sweeps: {', '.join(SWEEPS)}")
    if quick or variants:
        raise ConfigError("--sweep runs its own cases once each: no --quick, no --variant")
    return BenchPlan(cases=list(POSE_SWEEP), variants=["full"], sets=[], until="poses")


def _plan(quick: bool) -> BenchPlan:
    if quick:
        return BenchPlan(
            cases=[
                BenchCase(name="colon_q", shape="colon", frames=24, width=160, height=128, seed=7)
            ],
            variants=["full", "no_prior", "plain"],
            sets=["nerf.train.steps=400", "mesh.method=tsdf"],
        )
    return BenchPlan(
        cases=[
            BenchCase(name="colon", shape="colon", frames=60, width=320, height=256, seed=7),
            BenchCase(name="cavity", shape="cavity", frames=60, width=320, height=256, seed=7),
            # the lens cases: the bench colon through a 110-degree barrel lens, given and
            # estimated (OPENCV: the synth lens's own model), and its pinhole twin at 110 deg
            BenchCase(**COLON, name="colon_wide", fov_diag=110.0),
            BenchCase(**COLON, name="colon_barrel", lens="barrel"),
            BenchCase(
                **COLON,
                name="colon_barrel_est",
                lens="barrel",
                given_lens=False,
                sets=["poses.camera_model=OPENCV"],
            ),
            # a 140-degree fisheye, the lens estimated as any scope's is (SIMPLE_RADIAL, which
            # bends back inside it: re-fitted as a fisheye, poses.unfold_lens)
            BenchCase(**COLON, name="colon_fisheye_est", lens="fisheye", given_lens=False),
            # moving anatomy: the bench colon breathing (the same camera path), and a still
            # camera on the cavity's wall pulled by a tool in view (run as a user would: the
            # poses stage finds the camera still and poses it once)
            BenchCase(**COLON, name="colon_breathe", deform="breathe"),
            BenchCase(**PULL_STILL, name="pull_still"),
            # the same in EndoNeRF's layout, its depth/ matched from a right eye as EndoNeRF's
            # own: the depth the data set ships supervises, in mm
            BenchCase(**PULL_STILL, name="pull_still_endonerf", layout="endonerf", stereo=True),
            # a rectified Hamlyn sequence with both eyes, read as the data set ships (no GT
            # poses used: the stereo gives the scale), moving and still
            BenchCase(**COLON, name="hamlyn_stereo", layout="hamlyn", stereo=True),
            BenchCase(
                **COLON, name="hamlyn_stereo_still", layout="hamlyn", stereo=True, still_camera=True
            ),
            # the same still rig over the cavity: at its distances (12-33 mm) the right eye sees
            # most of the left one's view, as a laparoscope's does; the colon's near wall (8 mm)
            # puts 30% of the width out of the right eye's sight
            BenchCase(
                **{**COLON, "shape": "cavity"},
                name="hamlyn_stereo_still_cavity",
                layout="hamlyn",
                stereo=True,
                still_camera=True,
            ),
            # C3VD's layout: its calibration read as the lens, its model mesh the Chamfer truth
            BenchCase(**COLON, name="c3vd_layout", layout="c3vd"),
        ],
        variants=list(VARIANTS),
        sets=[],
    )
