"""The poses stage's settings: where poses come from, and COLMAP's options tuned for endoscopy."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, Field

from endopipe.pipeline.stage import StageConfig

CameraModelName = Literal[
    "SIMPLE_RADIAL",
    "RADIAL",
    "SIMPLE_PINHOLE",
    "PINHOLE",
    "OPENCV",
    "SIMPLE_RADIAL_FISHEYE",
    "RADIAL_FISHEYE",
    "OPENCV_FISHEYE",
]


class MotionConfig(BaseModel):
    """How the footage's motion is judged (poses.motion)."""

    check: bool = Field(
        True,
        description="Judge whether the camera moves and the scene holds still before SfM; a "
        "still camera gets one fixed pose instead of a path made of the tissue's motion.",
    )
    span_s: float = Field(
        1.0, gt=0.0, description="Seconds over which corners are tracked (the baseline)."
    )
    fps: float = Field(
        25.0, gt=0.0, description="Frame rate assumed for inputs without time (image folders)."
    )
    still_corner: float = Field(
        0.008,
        gt=0.0,
        description="A corner stayed put when it ended a span within this of where it started "
        "(a fraction of the image diagonal: about 3 px at the 320-px working size, above the "
        "tracker's drift over a second of lossy video), and one homography explains a corner "
        "it brings within this of where the corner went.",
    )
    still_share: float = Field(
        0.2,
        ge=0.0,
        le=1.0,
        description="The camera stands still only when at least this share of the tracked "
        "corners stayed put (median over the spans; a span whose view changed counts 0). "
        "Measured: still cameras 0.54 (a fixed da Vinci camera, tissue moving in most of the "
        "view), synthetic pulls and breathing 0.58-0.97; moving scopes 0-0.073 (C3VD).",
    )
    identity_part: float = Field(
        0.5,
        ge=0.0,
        le=1.0,
        description="... and when standing still explains at least this part of what one "
        "global motion does: the corners that stayed put over those the homography that "
        "explains most (RANSAC, within still_corner) explains, median over the spans. A moving "
        "camera moves nearly every corner with one motion (a zoom leaves those near its centre "
        "put, but one homography explains all); moving tissue does not follow one motion with "
        "the rest of the view. Measured: still cameras 0.84-1 (the da Vinci camera 0.86); "
        "moving scopes 0-0.17 (C3VD).",
    )
    min_kept: float = Field(
        0.1,
        ge=0.0,
        le=1.0,
        description="A span that kept fewer than this share of its corners (or under 10) to its "
        "end saw the view change: it counts as a moving camera's (nothing stayed put). Measured "
        "median kept: a moving sinus scope 0.003; still cameras 0.19 (a synthetic pull so hard "
        "that most pulled corners were lost) to 0.96.",
    )
    moving_corner: float = Field(
        0.004,
        gt=0.0,
        description="Under a still camera a corner that strays farther than this from where it "
        "started (a fraction of the diagonal) moved with the scene.",
    )
    deforming_share: float = Field(
        0.1,
        ge=0.0,
        le=1.0,
        description="Under a still camera the scene moves (tissue, instruments) when more than "
        "this share of the corners moved.",
    )
    corners: int = Field(300, ge=20, description="Corners tracked from the start of each span.")
    spans: int = Field(12, ge=1, description="Spans sampled evenly over the footage.")
    assumed_hfov_deg: float = Field(
        60.0,
        gt=10.0,
        lt=170.0,
        description="A still camera without known intrinsics (no parallax to estimate them "
        "from): the horizontal field of view assumed, and said to be assumed (a da Vinci "
        "endoscope: 59 degrees). Depth is then relative anyway.",
    )


class VerdictConfig(BaseModel):
    """When a frame or a sequence is called doubtful."""

    min_frame_points: int = Field(
        40, ge=0, description="A frame seeing fewer triangulated points is doubtful."
    )
    max_frame_reprojection_px: float = Field(
        2.0, gt=0, description="A frame whose mean reprojection error is larger is doubtful."
    )
    max_jump: float = Field(
        6.0,
        gt=1,
        description="A step (move or turn) between two frames longer than this many times the "
        "median step makes both frames doubtful.",
    )
    min_jump_deg: float = Field(
        1.0, ge=0, description="Turns smaller than this (deg) are never a jump."
    )
    min_link_share: float = Field(
        0.35,
        ge=0,
        le=1,
        description="A cut between consecutive registered frames is weak when the points seen on "
        "both sides are a smaller share than this of those its 3 neighbouring frames see on the "
        "thinner side: the stretches either side are hardly placed against each other, the "
        "sequence is doubtful and a recording poses them as separate segments (healthy "
        "models: 0.70 or more; a sinus stretch glued on 61 degrees wrong: 0.23).",
    )
    max_depth_drift: float = Field(
        4.0,
        gt=1,
        description="Scale drift: the sequence is doubtful when the frames' median scene depth "
        "(5-frame running median) changes by more than this factor along the path.",
    )
    max_disagreement_pct: float = Field(
        5.0,
        gt=0,
        description="Two mappers that both look sound but place the cameras this far apart (RMS, "
        "% of the path, after a similarity) make the sequence doubtful; a frame this far from "
        "the other mapper's is doubtful.",
    )
    max_focal_ratio: float = Field(
        1.25,
        gt=1,
        description="Two mappers that both look sound but whose self-calibrated focal lengths "
        "differ by more than this factor make the sequence doubtful, and the other mapper is "
        "not offered as the alternative.",
    )
    max_doubtful_frames: float = Field(
        0.2, ge=0, le=1, description="A sequence with a larger share of doubtful frames is."
    )
    min_registered: float = Field(
        0.9, ge=0, le=1, description="A sequence registering a smaller share of frames is."
    )
    on_doubtful: Literal["warn", "refuse"] = Field(
        "warn",
        description="warn: go on and say so (summary, report, batch.csv); refuse: stop with one "
        "line (exit 3) saying what to try.",
    )


class PosesConfig(StageConfig):
    source: Literal["colmap", "gt", "file", "known"] = Field(
        "colmap",
        description="Where poses come from: COLMAP SfM on the frames, the input's ground truth "
        "(a case's gt/poses.json or a data set's pose files), poses.file, or the poses the input "
        "came with that are not ground truth (known: EndoNeRF's poses_bounds.npy, SCARED's "
        "kinematics), taken as they are. With colmap, SfM's path is compared with known poses.",
    )
    file: str | None = Field(
        None,
        description="For source=file: a COLMAP model folder (text or binary) or a transforms.json "
        "(OpenGL convention). Images are matched to frames by name, else by the number in it.",
    )
    min_registered: float = Field(
        0.7, ge=0, le=1, description="Fail when fewer than this share of the frames get a pose."
    )
    align_to_gt: bool = Field(
        True,
        description="With ground-truth poses in the input, move the reconstruction onto them "
        "(sim3 on camera centres): GT world frame, millimetres, metric=true. Not with a stereo "
        "rig: its depth gives the scale, and the truth only scores.",
    )
    seed: int = Field(0, ge=0, description="Seed of every random choice (RANSAC, mapper).")
    num_threads: int = Field(
        1,
        ge=-1,
        description="Matching and mapper threads. 1 makes two runs agree (COLMAP is "
        "deterministic only single-threaded); -1 = all cores.",
    )
    clahe: bool = Field(
        True, description="Extract features on CLAHE-equalised grey images (more SIFT on mucosa)."
    )
    clahe_clip_limit: float = Field(2.0, gt=0, description="CLAHE contrast clip limit.")
    clahe_tiles: int = Field(8, ge=1, description="CLAHE tiles per image side.")
    use_masks: bool = Field(
        True, description="Ignore features outside the ingest masks (scope border, speculars)."
    )
    mask_grow_px: int = Field(
        3,
        ge=0,
        description="Grow the specular holes of the mask by this much for feature extraction "
        "(synthetic colon, 60 frames: ATE 1.46% of the path with 0, 0.25% with 5 px in total).",
    )
    sift_peak_threshold: float = Field(
        0.002,
        gt=0,
        description="SIFT peak threshold (COLMAP default 0.0067): lower finds features on "
        "low-contrast tissue.",
    )
    sift_max_features: int = Field(4096, ge=64, description="At most this many SIFT features.")
    sift_domain_size_pooling: bool = Field(
        True, description="Domain-size pooling of SIFT descriptors (more robust, CPU only)."
    )
    matcher: Literal["sequential", "exhaustive"] = Field(
        "sequential", description="sequential: each frame with its next neighbours (video order)."
    )
    sequential_overlap: int = Field(
        15, ge=1, description="Sequential matching: neighbours each frame is matched with."
    )
    quadratic_overlap: bool = Field(
        True, description="Sequential matching: also match frames 2^k apart."
    )
    mapper: Literal["auto", "both", "global", "incremental"] = Field(
        "auto",
        description="COLMAP mapper. auto: the global mapper, and the incremental one on the same "
        "matches only when the verdict finds the global poses doubtful on their own (a second "
        "opinion; the sounder is kept). both: always both (their disagreement, and that of their "
        "self-calibrated lenses, is evidence too; C3VD: +170 s, and a wrong second lens that made "
        "sound poses doubtful).",
    )
    motion: MotionConfig = Field(
        default_factory=MotionConfig,
        description="Whether the camera moves and the scene holds still, judged before SfM.",
    )
    verdict: VerdictConfig = Field(
        default_factory=VerdictConfig,
        description="When SfM poses are called doubtful (no ground truth needed).",
    )
    init_min_num_inliers: int = Field(
        30, ge=8, description="Mapper: inliers the initial pair needs (COLMAP default 100)."
    )
    abs_pose_min_num_inliers: int = Field(
        15, ge=6, description="Mapper: inliers a new frame needs to register (COLMAP default 30)."
    )
    init_min_tri_angle: float = Field(
        2.0,
        gt=0,
        description="Mapper: triangulation angle (deg) of the initial pair (COLMAP default 16; "
        "endoscopes move little between frames).",
    )
    min_model_size: int = Field(
        10,
        ge=2,
        description="Mapper: models with fewer frames are dropped (when there are several).",
    )
    camera_model: CameraModelName = Field(
        "SIMPLE_RADIAL",
        description="COLMAP camera model estimated when the intrinsics are unknown.",
    )
    unfold_lens: bool = Field(
        True,
        description="An estimated lens that bends back inside the field of view (SIMPLE_RADIAL "
        "through a wide scope) is re-fitted as a one-parameter fisheye (FOV) by bundle "
        "adjustment and written as OPENCV_FISHEYE: every pixel gets a ray, and the outer angles "
        "are not squeezed. Known intrinsics are not touched.",
    )
    focal_factor: float = Field(
        0.5,
        gt=0,
        description="Initial focal length of an estimated camera, as a multiple of the larger "
        "image side: 0.5 is 90 degrees across, a scope's width (COLMAP's own 1.2, 45 degrees, "
        "left C3VD's lens at half its width). Known intrinsics are not touched.",
    )
    refine_known_intrinsics: bool = Field(
        False,
        description="Let bundle adjustment refine known intrinsics (default: keep them fixed).",
    )
    refine_principal_point: bool = Field(
        False, description="When intrinsics are refined, refine the principal point too."
    )
    merge_models: bool = Field(
        True,
        description="When COLMAP leaves frames out (several models), continue the largest model "
        "with relaxed registration to add them.",
    )
    triangulate_known: bool = Field(
        True,
        description="With source=gt|file: triangulate sparse points from the known poses (the "
        "centerline stage measures the lumen radius from them; a file's own points are kept).",
    )
    keep_database: bool = Field(
        False, description="Keep COLMAP's database.db in 02_poses/colmap/ (for debugging)."
    )
    colmap_log: bool = Field(False, description="Show COLMAP's own log on stderr.")
