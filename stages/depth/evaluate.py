"""The depth stage's evaluation (docs/formats.md): both depth protocols against the ground truth,
which it reaches only through `open_ground_truth` / `depth_of_frame`, the same protocols for
the two guesses of `metrics.baselines` beside ours, and PSNR / SSIM of the held-out frames."""

from __future__ import annotations

import cv2
import numpy as np

from endopipe.stages.camera import Camera, image_directions
from endopipe.stages.ingest.view import IngestView
from endopipe.stages.io.ground_truth import GroundTruthSource, depth_of_frame
from endopipe.stages.metrics.baselines import (
    brightness_guess,
    neighbour_guesses,
    radial_guess,
)
from endopipe.stages.metrics.depth import (
    affine_sequence_metrics,
    image_metrics,
    sequence_protocol,
)
from endopipe.stages.metrics.exposure import exposure_matched
from endopipe.stages.nerf.shading_depth import shading_depth

#: The baseline name of the user's depth prior (`--depth-prior`) in `baselines`.
PRIOR = "depth_prior"
#: ... and a still camera's depth from shading (nerf.shading_depth), relative too
SHADING = "shading"


def ground_truth_depths(
    gt: GroundTruthSource | None, ingest: IngestView, indices: list[int]
) -> dict[int, np.ndarray]:
    """GT depth per frame at the working resolution (nearest-neighbour, no blending of edges)."""
    if gt is None:
        return {}
    out = {}
    for i in indices:
        d = depth_of_frame(gt, ingest.frame(i))
        if d is None:
            continue
        if d.shape != (ingest.height, ingest.width):
            d = cv2.resize(d, (ingest.width, ingest.height), interpolation=cv2.INTER_NEAREST)
        out[i] = d.astype(np.float32)
    return out


def guesses(
    ingest: IngestView, ids: list[int], inside: np.ndarray, principal: tuple[float, float]
) -> dict[str, list[np.ndarray]]:
    """The two guesses of `metrics.baselines` for frames `ids`, on the working grid."""
    radial = radial_guess(ingest.height, ingest.width, *principal, inside)
    return {
        "radial": [radial] * len(ids),
        "brightness": [brightness_guess(ingest.image(i)) for i in ids],
    }


def inside_view(ingest: IngestView) -> np.ndarray:
    """The pixels inside the scope's field of view (every pixel when there is no fov mask)."""
    fov = ingest.fov()
    return fov > 0 if fov is not None else np.ones((ingest.height, ingest.width), bool)


def scored_pixels(
    ingest: IngestView, ids: list[int], inside: np.ndarray
) -> tuple[list[np.ndarray], float | None]:
    """The pixels of frames `ids` whose depth is scored: inside the field of view and off a
    tool; and the share of the view left out for being on a tool (None without tool masks).
    On a tool the truth is the tool's surface, while ours is the tissue the field infers under
    it (docs/formats.md): scored there, a tool would count as our error. The deformable
    family's evaluations (EndoNeRF, Deform3DGS) leave tools out alike."""
    tools = [ingest.tool_mask(i) for i in ids]
    masks = [inside if t is None else inside & ~t for t in tools]
    shares = [(t & inside).sum() / max(int(inside.sum()), 1) for t in tools if t is not None]
    return masks, float(np.mean(shares)) if shares else None


def evaluate(
    gt: GroundTruthSource | None,
    ingest: IngestView,
    depths: dict[int, np.ndarray],
    gt_depths: dict[int, np.ndarray],
    rgbs: dict[int, np.ndarray],
    principal: tuple[float, float] | None = None,
    metric: bool = False,
    stereo: dict[int, np.ndarray] | None = None,
    prior: dict[int, np.ndarray] | None = None,
    shading: dict[int, np.ndarray] | None = None,
    fit_exposure: bool = False,
) -> dict:
    """Both depth protocols per frame and mean; PSNR / SSIM on held-out frames.
    `baselines` holds the same protocol blocks (means, no per-frame list) for the radial and
    brightness guesses, scored on exactly our pixels: where the ground truth is valid, inside
    the field of view, off a tool (`scored_pixels`) and ours has a depth, so a hole in ours is
    no easy pixel dropped for us alone (their coverage is therefore ours). `principal` is the
    camera's (cx, cy) on the working grid (the image centre when None). `metric` poses add the
    unscaled block; a stereo rig's depth maps (`stereo`, by frame) are scored beside ours as a
    guess is, and so are the user's depth prior (`prior`, by frame) and a still camera's depth
    from shading (`shading`), both relative: no unscaled block. `fit_exposure` (a field with an
    exposure a frame): each held-out render's exposure and its neighbour average's fitted to the
    frame, as the nerf stage scored them (metrics/exposure.py). The dict is metrics.json's
    content, which the stage writes as `DepthMetrics`."""
    metrics: dict = {}
    if gt_depths:
        inside = inside_view(ingest)
        ids = sorted(gt_depths)
        kind = getattr(gt, "kind", "exact")
        sequence = sequence_protocol(gt, metric)
        ours = [depths[i] for i in ids]
        truth = [gt_depths[i] for i in ids]
        masks, tool_share = scored_pixels(ingest, ids, inside)
        metrics.update(sequence(ours, truth, masks, ids))
        metrics["gt_kind"] = kind
        metrics["tool_share_left_out"] = tool_share
        centre = principal or ((ingest.width - 1) / 2, (ingest.height - 1) / 2)
        metrics["baselines"] = {}
        maps_of = guesses(ingest, ids, inside, centre)
        empty = np.zeros((ingest.height, ingest.width), np.float32)
        for name, given in (("stereo", stereo), (PRIOR, prior), (SHADING, shading)):
            if given:
                maps_of[name] = [given.get(i, empty) for i in ids]
        for name, maps in maps_of.items():
            same_pixels = [
                np.where((d > 0) & np.isfinite(d), g, 0).astype(np.float32)
                for d, g in zip(ours, maps, strict=True)
            ]
            scored = sequence(same_pixels, truth, masks, ids)
            scored.pop("per_frame")
            if name in (PRIOR, SHADING):  # relative: its own units mean nothing
                scored.pop("unscaled", None)
            metrics["baselines"][name] = scored
    if rgbs:
        ids = sorted(rgbs)
        per = {}
        for i in ids:
            frame = ingest.image(i).astype(np.float32) / 255.0
            rgb = rgbs[i]
            if fit_exposure:
                rgb = exposure_matched(rgb, frame, ingest.mask(i) > 127)[0]
            per[i] = image_metrics(rgb, frame, ingest.mask(i) > 127)
        metrics["heldout_frames"] = ids
        metrics["heldout_psnr"] = float(np.mean([p["psnr"] for p in per.values()]))
        metrics["heldout_ssim"] = float(np.mean([p["ssim"] for p in per.values()]))
        metrics["per_frame_image"] = {str(i): per[i] for i in ids}
        metrics["neighbour_average"] = neighbour_scores(ingest, ids, fit_exposure)
    return metrics


def neighbour_scores(
    ingest: IngestView, held: list[int], fit_exposure: bool = False
) -> dict[str, float]:
    """PSNR / SSIM of the held-out frames predicted by averaging their neighbours (the nearest
    frames before and after that were trained on), on the same pixels as ours, the exposure
    fitted to the frame as ours is (`fit_exposure`)."""
    order = [f.index for f in ingest.frames]
    rows = [
        image_metrics(guess, frame, m)
        for frame, guess, m in neighbour_guesses(
            lambda i: ingest.image(i).astype(np.float32) / 255.0,
            lambda i: ingest.mask(i) > 127,
            order,
            held,
            set(held),
            fit_exposure,
        )
    ]
    if not rows:
        return {}
    return {k: float(np.mean([r[k] for r in rows])) for k in ("psnr", "ssim")}


def scores_by_support(
    gt: GroundTruthSource | None,
    ingest: IngestView,
    depths: dict[int, np.ndarray],
    gt_depths: dict[int, np.ndarray],
    seen_again: dict[int, np.ndarray],
) -> dict[str, dict]:
    """The headline protocol block of ours on the pixels other views agree with and on the
    rest: do the views maps tell the better depth from the worse?"""
    ids = [i for i in sorted(gt_depths) if i in seen_again]
    if not ids:
        return {}
    sequence = sequence_protocol(gt)
    block = "affine_invariant" if sequence is affine_sequence_metrics else "median_scaled"
    truth = [gt_depths[i] for i in ids]
    inside = inside_view(ingest)
    masks, _ = scored_pixels(ingest, ids, inside)
    out = {}
    for name, keep in (("seen_again", True), ("rest", False)):
        ours = [np.where(seen_again[i] == keep, depths[i], 0.0).astype(np.float32) for i in ids]
        if any((d > 0).any() for d in ours):
            out[name] = sequence(ours, truth, masks, ids)[block]
    return out


def prior_maps(ingest: IngestView, ids: list[int]) -> dict[int, np.ndarray]:
    """The user's depth prior of frames `ids` ({} without one): scored beside ours."""
    if not ingest.has_depth_prior:
        return {}
    return {i: d for i in ids if (d := ingest.depth_prior(i)) is not None}


def shading_maps(
    ingest: IngestView, camera: Camera, ids: list[int], gamma: float
) -> dict[int, np.ndarray]:
    """Each frame's depth from shading (nerf.shading_depth) for a still camera with nothing
    else to place depth: scored beside ours, a guess from the light alone that ours must beat."""
    directions = image_directions(camera)
    return {i: shading_depth(ingest.image(i), ingest.mask(i) > 127, directions, gamma) for i in ids}


def stereo_maps(ingest: IngestView, ids: list[int]) -> dict[int, np.ndarray]:
    """The stereo rig's depth of frames `ids` ({} without a rig): scored beside ours."""
    if not ingest.has_stereo:
        return {}
    return {i: d for i in ids if (d := ingest.stereo_depth(i)) is not None}
