"""ingest: frames from a video, image folder or case folder; selection; scope and specular masks."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from rich.markup import escape

from endopipe.pipeline.errors import InputError
from endopipe.pipeline.stage import Stage, StageContext, write_json
from endopipe.stages.ingest.config import IngestConfig
from endopipe.stages.ingest.masks import combine, fov_mask_for_sequence, specular_mask
from endopipe.stages.ingest.prior_frames import FramePrior
from endopipe.stages.ingest.selection import Selection, select_frames, too_few_frames
from endopipe.stages.ingest.stereo_frames import FrameStereo
from endopipe.stages.ingest.summary import IngestSummary
from endopipe.stages.ingest.tool_frames import FrameTools
from endopipe.stages.ingest.view import (
    FOV_FILE,
    FRAMES_FILE,
    FrameEntry,
    FramesFile,
    IngestView,
    KnownPoses,
    SourceInfo,
    StereoInfo,
)
from endopipe.stages.io.added import AddedInputs
from endopipe.stages.io.calibration_check import CalibrationFit, fit_to_frames
from endopipe.stages.io.ground_truth import Coverage, coverage
from endopipe.stages.io.input_source import Frame, InputSource
from endopipe.stages.io.sources import open_input

__all__ = ["FrameEntry", "Ingest", "IngestConfig", "IngestSummary", "IngestView"]

#: What a run of a stereo pair alone does, said once by ingest and kept in frames.json.
ONE_PAIR = (
    "one stereo pair ({n} frame(s), too few to pose): depth from the rig alone, in mm; no "
    "camera path (one view has no motion to measure) and no field (one view teaches it nothing "
    "the stereo does not already say)"
)


class Ingest(Stage):
    """Read frames, select them, mask the scope border and specular highlights."""

    name = "ingest"
    needs = ()
    # 11: no stereo depth on a tool; 10: a stereo pair alone; 9: a calibration checked against
    # the frames' size; 8: a rig checked against its images (pairing, rows); 7: a data set's
    # metric depth in stereo/; 6: the user's depth prior
    version = 11
    Config = IngestConfig
    Summary = IngestSummary
    View = IngestView

    def run(self, ctx: StageContext[IngestConfig]) -> IngestSummary:
        cfg = ctx.config
        source = open_input(
            Path(ctx.case.input),
            Path(ctx.case.intrinsics_file) if ctx.case.intrinsics_file else None,
            format=ctx.case.kind,
            added=AddedInputs.of_case(ctx.case),
        )
        pair_alone = source.stereo is not None and cfg.stereo.mode != "off"
        selection = select_frames(source, cfg, ctx, fewest=1 if pair_alone else None)
        frames, dropped, size = selection.frames, selection.dropped, selection.size
        images = [f.rgb for f in frames]  # at the working size already
        fov, fov_shape = fov_mask_for_sequence(images[:: max(1, len(images) // 12)], cfg.fov)
        (ctx.out / "frames").mkdir()
        (ctx.out / "masks").mkdir()
        cv2.imwrite(str(ctx.out / FOV_FILE), fov)
        entries, spec_fracs, tool_fracs = [], [], []
        stereo_shares: list[float | None] = []
        tools = FrameTools(source.tool_masks, cfg.tools)
        calibration = source_intrinsics(source, selection.source_size, size)
        intrinsics = calibration.camera if calibration else None
        calibration_said = (calibration.said if calibration else None) or source.calibration_said
        if calibration_said:
            warn(ctx, calibration_said)
        stereo = FrameStereo(source.stereo, intrinsics, cfg.stereo, source.given_depth)
        kept = [f.source_index for f in frames]
        rig = stereo.check(
            kept, images if len(frames) >= cfg.min_frames else source_frames(source, kept)
        )
        if rig is not None:
            ctx.log(rig.said)
        one_pair = None
        if len(frames) < cfg.min_frames:
            if not stereo.active:
                raise InputError(f"{too_few_frames(source, selection, cfg)} ({stereo.skipped})")
            one_pair = ONE_PAIR.format(n=len(frames))
            ctx.log(one_pair)
        prior = FramePrior(source.depth_prior, selection.source_size)
        prior_frames = 0
        if tools.active:
            (ctx.out / "tools").mkdir()
        with ctx.progress("masks", total=len(images)) as advance:
            for i, (frame, rgb) in enumerate(zip(frames, images, strict=True)):
                spec = specular_mask(rgb, cfg.specular, fov)
                spec_fracs.append(float((spec > 0).mean()))
                name = f"{i:06d}.png"
                cv2.imwrite(str(ctx.out / "frames" / name), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
                usable = combine(fov, spec)
                tool = tools.of(frame.source_index, rgb, fov, size)
                if tool is not None:  # before the stereo: a tool's depth is not the tissue's
                    usable[tool] = 0
                    tool_fracs.append(float(tool.mean()))
                    cv2.imwrite(str(ctx.out / "tools" / name), tool.astype(np.uint8) * 255)
                depth = stereo.of(frame.source_index, rgb, usable) if stereo.active else None
                relative = prior.of(frame.source_index, size, fov) if prior.active else None
                prior_frames += relative is not None
                stereo_shares.append(None if depth is None else stereo.share(depth, fov))
                cv2.imwrite(str(ctx.out / "masks" / name), usable)
                entries.append(
                    FrameEntry(
                        index=i,
                        source_index=frame.source_index,
                        time_s=frame.time_s,
                        file=f"frames/{name}",
                        mask=f"masks/{name}",
                        tool=f"tools/{name}" if tool is not None else None,
                        tool_share=float(tool.mean()) if tool is not None else None,
                        stereo=None if depth is None else stereo.write(ctx.out, name[:-4], depth),
                        stereo_share=stereo_shares[-1],
                        depth_prior=None
                        if relative is None
                        else prior.write(ctx.out, name[:-4], relative),
                    )
                )
                advance()
        frames_file = FramesFile(
            frames=entries,
            intrinsics=intrinsics,
            width=size[0],
            height=size[1],
            source=SourceInfo(path=str(source.path), kind=source.kind),
            gt_dir=str(source.gt_dir) if source.gt_dir else None,
            fov_shape=fov_shape,
            dropped=dropped,
            tools=tools.said if tools.active else None,
            known_poses=known_poses(source, entries),
            dropped_frames=selection.dropped_frames or {},
            stereo=stereo_info(stereo),
            depth_prior=str(source.depth_prior.folder) if source.depth_prior else None,
            one_pair=one_pair is not None,
        )
        write_json(ctx.out / FRAMES_FILE, frames_file.model_dump(mode="json"))
        write_contact_sheet(
            ctx.out / "contact_sheet.png", images, fov, ctx.out, cfg.contact_sheet_frames
        )
        kind = "keyframes by content" if selection.keyframes else "frames"
        ctx.log(f"{kept_line(len(frames), selection, kind)}; field of view: {fov_shape}")
        if source.kind == "case" and source.intrinsics is None:
            ctx.log("the case has no intrinsics.json: COLMAP estimates the camera")
        if tools.active:
            ctx.log(tools.line(tool_fracs))
        for note in source.notes:  # what the reader did: a lens fitted, frames cropped, --right
            ctx.log(note)
        if stereo.active or source.stereo is not None or source.given_depth is not None:
            ctx.log(stereo.line(stereo_shares))
        if prior.active:
            ctx.log(prior.line(prior_frames, len(frames)))
        poses_said = known_poses_said(frames_file.known_poses)
        if poses_said:
            ctx.log(poses_said)
        gt = ground_truth_coverage(ctx, source, frames, selection.total)
        return IngestSummary(
            kind=source.kind,
            source_frames=selection.total,
            read=selection.read,
            kept=len(frames),
            dropped=dropped,
            keyframes=selection.keyframes,
            width=size[0],
            height=size[1],
            fov_shape=fov_shape,
            fov_fraction=float((fov > 0).mean()),
            mean_specular_fraction=float(np.mean(spec_fracs)),
            tool_masks=tools.where if tools.active else None,
            tool_polarity=tools.polarity if tools.active else None,
            frames_with_tools=sum(f > 0 for f in tool_fracs) if tools.active else None,
            mean_tool_fraction=float(np.mean(tool_fracs)) if tools.active else None,
            max_tool_fraction=float(max(tool_fracs)) if tools.active else None,
            known_poses=poses_said,
            stereo=stereo.source if stereo.active else None,
            stereo_baseline_mm=stereo.baseline_mm if stereo.active else None,
            stereo_coverage=stereo_shares if stereo.active else None,
            stereo_mean_coverage=mean_share(stereo_shares) if stereo.active else None,
            stereo_check=rig.said if rig is not None else None,
            depth_prior=str(source.depth_prior.folder) if source.depth_prior else None,
            depth_prior_frames=prior_frames if prior.active else None,
            has_intrinsics=intrinsics is not None,
            has_ground_truth=source.gt_dir is not None,
            gt_frames_without_depth=gt.frames_without_depth,
            gt_frames_without_pose=gt.frames_without_pose,
            calibration_check=calibration_said,
            one_pair=one_pair,
            warnings=[*([calibration_said] if calibration_said else []), *gt.warnings],
        )


def source_frames(source: InputSource, kept: list[int]) -> list[np.ndarray]:
    """The kept frames as the input holds them, at its own size (a pair alone: its rig is
    checked on them, where the one frame has four times the features of the working size)."""
    wanted = set(kept)
    return [f.rgb for f in source.frames() if f.source_index in wanted]


def ground_truth_coverage(
    ctx: StageContext, source: InputSource, frames: list[Frame], input_frames: int | None
) -> Coverage:
    """Warn (one line each) where the truth leaves kept frames unevaluated or does not match."""
    try:
        truth = source.ground_truth()
    except InputError as e:  # a gt/ with nothing readable: evaluation will say so too
        found = Coverage(warnings=[str(e)])
    else:
        found = coverage(truth, [f.source_index for f in frames], input_frames)
    for line in found.warnings:
        warn(ctx, line)
    return found


def stereo_info(stereo: FrameStereo) -> StereoInfo | None:
    """frames.json's account of where its stereo/ depth came from (a rig, or the data set)."""
    if not stereo.active:
        return None
    return StereoInfo(
        source=stereo.source, baseline_mm=stereo.baseline_mm, matcher=stereo.how, rig=stereo.rig
    )


def mean_share(shares: list[float | None]) -> float | None:
    """The mean over the frames that were matched (None when none was)."""
    got = [s for s in shares if s is not None]
    return float(np.mean(got)) if got else None


def known_poses(source: InputSource, entries: list[FrameEntry]) -> KnownPoses | None:
    """The input's own poses (EndoNeRF's) for the kept frames; never ground truth."""
    poses = source.known_poses
    if poses is None:
        return None
    c2w = {e.index: poses[e.source_index].tolist() for e in entries if e.source_index < len(poses)}
    return KnownPoses(source=source.known_poses_from or str(source.path), c2w=c2w)


def known_poses_said(known: KnownPoses | None) -> str | None:
    """'known poses: one for all 156 frames (a still camera), from ...; not ground truth'."""
    if known is None or not known.c2w:
        return None
    mats = np.array(list(known.c2w.values()))
    same = np.abs(mats - mats[0]).max() < 1e-9
    what = f"one for all {len(mats)} frames (a still camera)" if same else f"{len(mats)} frames"
    return f"known poses: {what}, from {known.source}; not ground truth, not scored"


def kept_line(kept: int, selection: Selection, kind: str = "frames") -> str:
    """'kept 60 of 250 frames (190 not read, 2 blank)': where every input frame went."""
    total = selection.total if selection.total is not None else f"{selection.read}+"
    reasons = ", ".join(
        f"{n} {reason.replace('_', ' ')}" for reason, n in selection.dropped.items() if n
    )
    return f"kept {kept} of {total} {kind}" + (f" ({reasons})" if reasons else "")


def warn(ctx: StageContext, message: str) -> None:
    """A warning is printed even with --quiet (which only hides progress)."""
    ctx.console.print(
        f"[yellow]warning:[/yellow] {escape(message)}", highlight=False, soft_wrap=True
    )


def source_intrinsics(
    source: InputSource, source_size: tuple[int, int], size: tuple[int, int]
) -> CalibrationFit | None:
    """Camera scaled to the working resolution; they must describe the source frames, and are
    checked against them (stages/io/calibration_check.py: one stated for another image size is
    rescaled aloud, one that fits no size refused)."""
    k = source.intrinsics
    if k is None:
        return None
    w, h = source_size
    if (k.width, k.height) != (w, h):
        if abs(k.width / k.height - w / h) > 0.01:
            raise InputError(
                f"intrinsics are for {k.width}x{k.height} but the frames are {w}x{h}; "
                "give intrinsics for this video"
            )
        k = k.scaled(w, h)
    fit = fit_to_frames(k, f"{source.kind} input")
    return CalibrationFit(fit.camera.scaled(*size), fit.said)


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
