"""The depth stage's evaluation (DESIGN §6): both depth protocols against the ground truth,
which it reaches only through `open_ground_truth` / `depth_of_frame`, and PSNR / SSIM of
the held-out frames."""

from __future__ import annotations

import cv2
import numpy as np

from endopipe.stages.ingest.view import IngestView
from endopipe.stages.io.ground_truth import GroundTruthSource, depth_of_frame
from endopipe.stages.metrics.depth import (
    affine_sequence_metrics,
    depth_sequence_metrics,
    image_metrics,
)


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


def evaluate(
    gt: GroundTruthSource | None,
    ingest: IngestView,
    depths: dict[int, np.ndarray],
    gt_depths: dict[int, np.ndarray],
    rgbs: dict[int, np.ndarray],
) -> dict:
    """DESIGN §6: both depth protocols per frame and mean; PSNR / SSIM on held-out frames.
    The dict is metrics.json as written (`DepthMetrics` reads it back)."""
    metrics: dict = {}
    if gt_depths:
        fov = ingest.fov()
        inside = fov > 0 if fov is not None else np.ones((ingest.height, ingest.width), bool)
        ids = sorted(gt_depths)
        kind = getattr(gt, "kind", "exact")
        # A relative ground truth (an affine proxy of depth) supports no metric protocol.
        sequence = affine_sequence_metrics if kind == "relative" else depth_sequence_metrics
        metrics.update(
            sequence(
                [depths[i] for i in ids], [gt_depths[i] for i in ids], [inside] * len(ids), ids
            )
        )
        metrics["gt_kind"] = kind
    if rgbs:
        ids = sorted(rgbs)
        per = {
            i: image_metrics(
                rgbs[i], ingest.image(i).astype(np.float32) / 255.0, ingest.mask(i) > 127
            )
            for i in ids
        }
        metrics["heldout_frames"] = ids
        metrics["heldout_psnr"] = float(np.mean([p["psnr"] for p in per.values()]))
        metrics["heldout_ssim"] = float(np.mean([p["ssim"] for p in per.values()]))
        metrics["per_frame_image"] = {str(i): per[i] for i in ids}
    return metrics
