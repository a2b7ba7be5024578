"""The ingest stage's summary, one model on both sides: the stage writes it into its manifest,
`IngestView.summary` reads it back, and report, bench and batch read its fields by name."""

from __future__ import annotations

from endopipe.pipeline.stage import Summary


class IngestSummary(Summary):
    kind: str
    source_frames: int | None  # None: unknown (decoding stopped early on a video of no length)
    read: int  # frames decoded (fewer than source_frames when max_frames stopped decoding)
    kept: int
    dropped: dict[str, int]  # frames not kept, by reason
    keyframes: bool = False  # frames kept by content (a recording), not every usable one
    width: int
    height: int
    fov_shape: str
    fov_fraction: float
    mean_specular_fraction: float
    #: tool masks: read with the input (a case folder's or EndoNeRF's masks/), or detected;
    #: where from, the polarity read ("255 = tool", "0 = tool", "detected"), and the share of
    #: the pixels they mark, mean and largest over the frames (None: no tool masks)
    tool_masks: str | None = None
    tool_polarity: str | None = None
    frames_with_tools: int | None = None
    mean_tool_fraction: float | None = None
    max_tool_fraction: float | None = None
    #: poses the input came with that are not ground truth (EndoNeRF's): what they say
    known_poses: str | None = None
    #: stereo depth from the input's right views (01_ingest/stereo/): where the rig was read,
    #: its baseline, and per kept frame (in frame order) the share of the field of view it
    #: covers (None: no right view for that frame); all None without stereo depth
    stereo: str | None = None
    stereo_baseline_mm: float | None = None
    stereo_coverage: list[float | None] | None = None
    stereo_mean_coverage: float | None = None
    #: the rig checked against its images (its pairing and rows), in one line; None: unchecked
    stereo_check: str | None = None
    #: the calibration checked against the frames (stages/io/calibration_check.py), in one line
    #: when it did not fit them as given (rescaled from another size, or doubtful); None: it fit
    calibration_check: str | None = None
    #: a stereo pair alone (too few frames to pose), in one line: depth from the rig only
    one_pair: str | None = None
    #: depth maps made elsewhere (`--depth-prior`, relative; 01_ingest/depth_prior/): the
    #: folder they were read from and how many kept frames had one (None: no prior given)
    depth_prior: str | None = None
    depth_prior_frames: int | None = None
    has_intrinsics: bool
    has_ground_truth: bool
    gt_frames_without_depth: int = 0  # kept frames the ground truth has no depth for
    gt_frames_without_pose: int = 0  # kept frames the ground truth has no pose for
    warnings: list[str] = []  # one line each: what the user should know (shown in the report)
