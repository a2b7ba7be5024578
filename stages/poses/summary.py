"""The poses stage's summary, one model on both sides: the stage writes it into its manifest,
`PosesView.summary` reads it back, and report, bench and batch read its fields by name."""

from __future__ import annotations

from pydantic import BaseModel, Field

from endopipe.pipeline.stage import Summary
from endopipe.stages.poses.lens import LensRefit
from endopipe.stages.poses.motion import FootageMotion


class KnownPosesCheck(BaseModel):
    """The poses kept beside the poses the input came with (EndoNeRF's poses_bounds.npy,
    SCARED's kinematics): not ground truth, so a check, never a score."""

    source: str = Field(description="where the input's own poses were read")
    #: both stand still or both move (None: compared by their paths instead)
    agree: bool | None = None
    #: ATE after a sim3 on the camera centres, % of the known path (None: a still one)
    ate_percent_of_path: float | None = None
    said: str = Field(description="the comparison in words")


class StereoScale(BaseModel):
    """Millimetres per SfM unit, from the stereo depth at the SfM points."""

    mm_per_unit: float
    points: int  # observations with both depths
    spread: float  # median |ratio / scale - 1|: how far one scale explains the points


class PosesSummary(Summary):
    source: str  # colmap | gt | file
    registered: int
    total: int
    registered_fraction: float
    unregistered: str  # frame ranges, e.g. "3-5, 9"
    camera_model: str  # COLMAP's name of the camera model
    intrinsics: str  # fixed | refined | estimated | assumed (a still camera, nothing known)
    fx: float
    fy: float
    cx: float
    cy: float
    metric: bool
    aligned_to_gt: bool
    points: int
    seconds: float
    # --- the reconstruction (SfM, or triangulated from known poses) ------------------------
    mapper: str = ""  # the mapper kept: global | incremental
    models: int = 0  # models the mapper split the sequence into
    model_sizes: list[int] = []
    merge: str = ""  # what merging the models did
    merged_frames: int = 0
    mean_reprojection_px: float | None = None
    mean_track_length: float | None = None
    mean_points_per_frame: float | None = None
    file: str | None = None  # source: file, the file the poses came from
    sim3_scale: float | None = None  # aligned to the ground truth: the similarity's scale
    #: seconds per step: features_s, matching_s, <mapper>_mapping_s, triangulation_s
    timings: dict[str, float] = {}
    # --- the verdict -------------------------------------------------------------------------
    verdict: str = "not assessed"
    verdict_reasons: str = ""
    doubtful_frames: str = ""
    mappers_disagreement_pct: float | None = None
    depth_drift: float | None = None
    # --- against ground truth poses ------------------------------------------------------------
    ate_mm: float | None = None  # in the ground truth's units
    ate_percent_of_path: float | None = None
    rre_deg: float | None = None
    gt_path_length_mm: float | None = None
    #: the ATE (% of path) the mappers not kept would have given
    others_ate_percent: dict[str, float] = {}
    #: share of the field of view's pixels the lens model gives a ray (the rest: no depth)
    lens_reach: float | None = None
    #: an estimated lens that bent back inside the field of view, re-fitted as a fisheye: how
    #: (`LensRefit.said` puts it in words)
    lens_refit: LensRefit | None = None
    #: an estimated lens: how far from the principal point (px) its features reach
    fitted_radius_px: float | None = None
    #: where the metric scale came from: "ground truth" (aligned to it), "stereo" (the rig's
    #: depth at the SfM points, or a still camera's own frame in mm), None: not metric
    metric_from: str | None = None
    #: the SfM poses scaled by the stereo depth: millimetres per SfM unit and how well one
    #: scale explains the points (None: not scaled by stereo)
    stereo_scale: StereoScale | None = None
    #: whether the camera moved and the scene held still, judged before SfM (None: not judged)
    motion: FootageMotion | None = None
    #: the poses kept against the input's own (None: it came with none, or they were kept)
    known_poses: KnownPosesCheck | None = None
