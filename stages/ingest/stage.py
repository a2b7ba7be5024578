"""ingest: frames from a video, image folder or case folder; selection; scope and specular masks."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from pydantic import Field

from endopipe.pipeline.errors import InputError
from endopipe.pipeline.stage import Stage, StageConfig, StageContext, Summary, write_json
from endopipe.stages.camera import Camera
from endopipe.stages.ingest.frame_quality import frame_difference, sharpness
from endopipe.stages.ingest.masks import (
    FovConfig,
    SpecularConfig,
    combine,
    fov_mask_for_sequence,
    specular_mask,
)
from endopipe.stages.io.sources import Frame, InputSource, open_input


class IngestConfig(StageConfig):
    stride: int = Field(1, ge=1, description="Keep every n-th frame of the input.")
    max_frames: int | None = Field(
        None, ge=1, description="Keep at most this many frames (after stride and filtering)."
    )
    start_s: float = Field(0.0, ge=0, description="Skip video before this time (seconds).")
    end_s: float | None = Field(None, gt=0, description="Stop reading the video at this time.")
    max_size: int = Field(
        320,
        ge=32,
        description="Working resolution: the longer image side, in pixels (downscale only).",
    )
    min_frames: int = Field(3, ge=2, description="Fewer usable frames than this is an error.")
    drop_duplicates: bool = Field(
        True, description="Drop frames nearly identical to the last kept one."
    )
    duplicate_threshold: float = Field(
        0.0015,
        ge=0,
        description="Mean absolute grey difference (0..1) under which a frame is a duplicate.",
    )
    drop_blurred: bool = Field(
        True, description="Drop frames much blurrier than the sequence median."
    )
    blur_rel_threshold: float = Field(
        0.35,
        ge=0,
        le=1,
        description="A frame is blurred when its sharpness < this x the median sharpness.",
    )
    black_level: float = Field(
        8.0, ge=0, description="A frame whose 99th-percentile grey level is under this is blank."
    )
    fov: FovConfig = Field(
        default_factory=FovConfig, description="Field-of-view (scope border) mask."
    )
    specular: SpecularConfig = Field(
        default_factory=SpecularConfig, description="Specular-highlight mask."
    )
    contact_sheet_frames: int = Field(16, ge=1, description="Frames shown in contact_sheet.png.")


class IngestSummary(Summary):
    kind: str
    source_frames: int
    kept: int
    dropped: dict[str, int]
    width: int
    height: int
    fov_shape: str
    fov_fraction: float
    mean_specular_fraction: float
    has_intrinsics: bool
    has_ground_truth: bool


@dataclass
class FrameEntry:
    index: int
    source_index: int
    time_s: float | None
    file: str
    mask: str


class IngestView:
    """Typed access to 01_ingest for downstream stages."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        data = json.loads((folder / "frames.json").read_text())
        self.frames = [FrameEntry(**f) for f in data["frames"]]
        self.intrinsics = Camera(**data["intrinsics"]) if data["intrinsics"] else None
        self.width: int = data["width"]
        self.height: int = data["height"]
        self.gt_dir = Path(data["gt_dir"]) if data.get("gt_dir") else None

    def image(self, i: int) -> np.ndarray:
        """RGB uint8 of frame i (endopipe index)."""
        return cv2.cvtColor(cv2.imread(str(self.folder / self.frames[i].file)), cv2.COLOR_BGR2RGB)

    def image_path(self, i: int) -> Path:
        return self.folder / self.frames[i].file

    def mask(self, i: int) -> np.ndarray:
        """uint8 mask, 255 = usable (inside the field of view, not specular)."""
        return cv2.imread(str(self.folder / self.frames[i].mask), cv2.IMREAD_GRAYSCALE)

    def fov(self) -> np.ndarray:
        return cv2.imread(str(self.folder / "fov_mask.png"), cv2.IMREAD_GRAYSCALE)


class Ingest(Stage):
    """Read frames, select them, mask the scope border and specular highlights."""

    name = "ingest"
    needs = ()
    version = 1
    Config = IngestConfig

    @classmethod
    def view(cls, folder: Path) -> IngestView:
        return IngestView(folder)

    def run(self, ctx: StageContext) -> IngestSummary:
        cfg: IngestConfig = ctx.config  # type: ignore[assignment]
        source = open_input(
            Path(ctx.case.input),
            Path(ctx.case.intrinsics_file) if ctx.case.intrinsics_file else None,
            format=ctx.case.kind,
        )
        frames, dropped, total = select_frames(source, cfg, ctx)
        size = working_size(frames[0].rgb.shape[1], frames[0].rgb.shape[0], cfg.max_size)
        images = [resize(f.rgb, size) for f in frames]
        fov, fov_shape = fov_mask_for_sequence(images[:: max(1, len(images) // 12)], cfg.fov)
        (ctx.out / "frames").mkdir()
        (ctx.out / "masks").mkdir()
        cv2.imwrite(str(ctx.out / "fov_mask.png"), fov)
        entries, spec_fracs = [], []
        with ctx.progress("masks", total=len(images)) as advance:
            for i, (frame, rgb) in enumerate(zip(frames, images, strict=True)):
                spec = specular_mask(rgb, cfg.specular, fov)
                spec_fracs.append(float((spec > 0).mean()))
                name = f"{i:06d}.png"
                cv2.imwrite(str(ctx.out / "frames" / name), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
                cv2.imwrite(str(ctx.out / "masks" / name), combine(fov, spec))
                entries.append(
                    FrameEntry(
                        i, frame.source_index, frame.time_s, f"frames/{name}", f"masks/{name}"
                    )
                )
                advance()
        intrinsics = source_intrinsics(source, frames[0].rgb.shape, size)
        write_json(
            ctx.out / "frames.json",
            {
                "frames": [e.__dict__ for e in entries],
                "intrinsics": intrinsics.model_dump() if intrinsics else None,
                "width": size[0],
                "height": size[1],
                "source": {"path": str(source.path), "kind": source.kind},
                "gt_dir": str(source.gt_dir) if source.gt_dir else None,
                "fov_shape": fov_shape,
                "dropped": dropped,
            },
        )
        write_contact_sheet(
            ctx.out / "contact_sheet.png", images, fov, ctx.out, cfg.contact_sheet_frames
        )
        ctx.log(
            f"kept {len(frames)} of {total} frames "
            + ", ".join(f"{v} {k}" for k, v in dropped.items() if v)
            + f"; field of view: {fov_shape}"
        )
        return IngestSummary(
            kind=source.kind,
            source_frames=total,
            kept=len(frames),
            dropped=dropped,
            width=size[0],
            height=size[1],
            fov_shape=fov_shape,
            fov_fraction=float((fov > 0).mean()),
            mean_specular_fraction=float(np.mean(spec_fracs)),
            has_intrinsics=intrinsics is not None,
            has_ground_truth=source.gt_dir is not None,
        )


def select_frames(
    source: InputSource, cfg: IngestConfig, ctx: StageContext
) -> tuple[list[Frame], dict[str, int], int]:
    """Stride, time window, blank / duplicate / blur filtering; reasons are counted."""
    dropped = {"outside_time_window": 0, "stride": 0, "blank": 0, "duplicate": 0, "blurred": 0}
    candidates: list[Frame] = []
    total = 0
    last_grey: np.ndarray | None = None
    with ctx.progress("decode", total=source.frame_count()) as advance:
        for frame in source.frames():
            total += 1
            advance()
            t = frame.time_s
            if t is not None and (t < cfg.start_s or (cfg.end_s is not None and t > cfg.end_s)):
                dropped["outside_time_window"] += 1
                continue
            if (total - 1) % cfg.stride:
                dropped["stride"] += 1
                continue
            grey = cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2GRAY)
            if np.percentile(grey, 99) < cfg.black_level:
                dropped["blank"] += 1
                continue
            if cfg.drop_duplicates and last_grey is not None:
                if frame_difference(grey, last_grey) < cfg.duplicate_threshold:
                    dropped["duplicate"] += 1
                    continue
            last_grey = grey
            candidates.append(frame)
    if total == 0:
        raise InputError(f"{source.path} holds no decodable frames; check the file")
    if not candidates:
        raise InputError(
            f"all {total} frames of {source.path} are blank (black) or outside the time window; "
            "check the video and --set ingest.start_s/end_s"
        )
    if cfg.drop_blurred and len(candidates) >= 3:
        scores = np.array([sharpness(f.rgb) for f in candidates])
        keep = scores >= cfg.blur_rel_threshold * np.median(scores)
        dropped["blurred"] = int((~keep).sum())
        candidates = [f for f, k in zip(candidates, keep, strict=True) if k]
    if cfg.max_frames is not None:
        candidates = candidates[: cfg.max_frames]
    if len(candidates) < cfg.min_frames:
        raise InputError(
            f"only {len(candidates)} usable frame(s) in {source.path} (of {total}); endopipe needs "
            f"at least {cfg.min_frames}: give a longer video or lower --set ingest.stride"
        )
    return candidates, dropped, total


def working_size(width: int, height: int, max_size: int) -> tuple[int, int]:
    scale = min(1.0, max_size / max(width, height))
    return max(1, round(width * scale)), max(1, round(height * scale))


def resize(rgb: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    if (rgb.shape[1], rgb.shape[0]) == size:
        return rgb
    return cv2.resize(rgb, size, interpolation=cv2.INTER_AREA)


def source_intrinsics(
    source: InputSource, shape: tuple[int, ...], size: tuple[int, int]
) -> Camera | None:
    """Camera scaled to the working resolution; they must describe the source frames."""
    k = source.intrinsics
    if k is None:
        return None
    h, w = shape[:2]
    if (k.width, k.height) != (w, h):
        if abs(k.width / k.height - w / h) > 0.01:
            raise InputError(
                f"intrinsics are for {k.width}x{k.height} but the frames are {w}x{h}; "
                "give intrinsics for this video"
            )
        k = k.scaled(w, h)
    return k.scaled(*size)


def write_contact_sheet(
    path: Path, images: list[np.ndarray], fov: np.ndarray, out: Path, count: int
) -> None:
    """Thumbnails with the masks overlaid: outside the field of view dimmed, speculars magenta."""
    picks = np.linspace(0, len(images) - 1, min(count, len(images))).round().astype(int)
    cols = int(np.ceil(np.sqrt(len(picks))))
    rows = int(np.ceil(len(picks) / cols))
    h, w = images[0].shape[:2]
    sheet = np.zeros((rows * h, cols * w, 3), np.uint8)
    for n, i in enumerate(picks):
        mask = cv2.imread(str(out / "masks" / f"{i:06d}.png"), cv2.IMREAD_GRAYSCALE)
        tile = images[i].copy()
        tile[fov == 0] = tile[fov == 0] // 3
        tile[(mask == 0) & (fov > 0)] = (255, 0, 255)
        cv2.putText(tile, str(i), (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (255, 255, 0), 1)
        r, c = divmod(n, cols)
        sheet[r * h : (r + 1) * h, c * w : (c + 1) * w] = tile
    cv2.imwrite(str(path), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR))
