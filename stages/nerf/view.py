"""04_nerf (docs/formats.md): the only reader of the NeRF stage's folder, beside the stage that
writes it: the trained model (through render.load_model, so inference never imports training), the
training log and plots, the held-out evaluation (metrics.json), the refined cameras
(cameras_refined.json, written when the poses were refined with the field) and the summary."""

from __future__ import annotations

import csv
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from pydantic import BaseModel

from endopipe.pipeline.cache import Manifest
from endopipe.pipeline.stage import read_summary
from endopipe.stages.nerf.files import (
    HELDOUT_PAIRS_FILE,
    HELDOUT_PLOT_FILE,
    HELDOUT_RGB_DIR,
    LOSS_PLOT_FILE,
    MODEL_FILE,
    REFINED_CAMERAS_FILE,
    TRAIN_LOG_FILE,
)
from endopipe.stages.nerf.metrics_file import NerfMetrics
from endopipe.stages.nerf.summary import NerfSummary

if TYPE_CHECKING:
    from endopipe.stages.nerf.model import NerfModel
    from endopipe.stages.poses.view import PosesView


class RefinedFrame(BaseModel):
    index: int
    c2w: list[list[float]]  # world frame and units of 02_poses/cameras.json, OpenCV
    heldout: bool = False


class RefinedCameras(BaseModel):
    """cameras_refined.json: the registered frames' poses after the joint refinement (same
    camera, world frame and units as cameras.json) and how far they moved (the summary's
    `pose_refine` block)."""

    convention: str = "opencv_c2w"
    frames: list[RefinedFrame]
    movement: dict[str, Any] = {}

    def write(self, folder: Path) -> None:
        (Path(folder) / REFINED_CAMERAS_FILE).write_text(self.model_dump_json(indent=1))


class NerfView:
    """Typed access to 04_nerf."""

    def __init__(self, folder: Path) -> None:
        self.folder = Path(folder)

    # --- the model --------------------------------------------------------------------------
    @property
    def model_path(self) -> Path:
        """model.pt: config, scene box, weights and meta (frame ids, train / held-out, units)."""
        return self.folder / MODEL_FILE

    @cached_property
    def summary(self) -> NerfSummary:
        """The stage's summary in its manifest, as the model the stage wrote (SummaryMismatch
        when the folder was written with other fields)."""
        return read_summary(self.folder, NerfSummary)

    @property
    def dynamic(self) -> bool:
        """Whether the field changes with time (the summary's `time_nodes`). A folder with no
        manifest (one put together by hand, or no NeRF at all) holds no dynamic field."""
        if Manifest.load(self.folder) is None:
            return False
        return self.summary.time_nodes is not None

    @property
    def trained(self) -> bool:
        """Whether a field was trained (a stereo pair alone has none: the summary says why)."""
        if Manifest.load(self.folder) is None:
            return self.model_path.is_file()
        return self.summary.skipped is None

    def model(self, device: str = "cpu") -> NerfModel:
        """The trained NerfModel, in eval mode; its `meta` says which frames were held out."""
        from endopipe.stages.nerf.render import load_model  # torch: only to load the model

        return load_model(self.model_path, device)

    # --- cameras ------------------------------------------------------------------------------
    @property
    def refined_cameras_path(self) -> Path:
        return self.folder / REFINED_CAMERAS_FILE

    @cached_property
    def refined_cameras(self) -> RefinedCameras | None:
        """cameras_refined.json; None when the poses were used as given."""
        path = self.refined_cameras_path
        if not path.is_file():
            return None
        return RefinedCameras.model_validate_json(path.read_text())

    def c2w(self, poses: PosesView) -> dict[int, np.ndarray]:
        """The registered frames' world c2w the field was fitted to: the refined poses when the
        NeRF refined them, else those of 02_poses. Depth maps and meshes use these, so they
        agree with the field."""
        refined = self.refined_cameras
        out = {i: np.asarray(c, np.float64) for i, c in poses.c2w.items()}
        if refined is not None:
            for f in refined.frames:
                if f.index in out:
                    out[f.index] = np.array(f.c2w, np.float64)
        return out

    # --- training -----------------------------------------------------------------------------
    @property
    def train_log_path(self) -> Path:
        return self.folder / TRAIN_LOG_FILE

    def train_log(self) -> list[dict[str, float | None]]:
        """train_log.csv as rows (step, loss, photo, ..., psnr); an empty cell is None."""
        if not self.train_log_path.is_file():
            return []
        with open(self.train_log_path, newline="") as fh:
            return [
                {k: float(v) if v not in ("", None) else None for k, v in row.items()}
                for row in csv.DictReader(fh)
            ]

    @property
    def loss_plot_path(self) -> Path:
        """loss.png: the training losses and training PSNR."""
        return self.folder / LOSS_PLOT_FILE

    @property
    def heldout_plot_path(self) -> Path:
        """heldout.png: held-out frames, their renderings and depth (absent without any)."""
        return self.folder / HELDOUT_PLOT_FILE

    @property
    def heldout_pairs_path(self) -> Path:
        """heldout_pairs.jpg: every held-out frame beside its render (absent without any)."""
        return self.folder / HELDOUT_PAIRS_FILE

    # --- evaluation ---------------------------------------------------------------------------
    @cached_property
    def metrics(self) -> NerfMetrics | None:
        """metrics.json: held-out frames, PSNR, render times and, with ground-truth depth,
        their depth scores; None when absent."""
        return NerfMetrics.read(self.folder)

    def heldout_rgb(self, index: int) -> np.ndarray | None:
        """Held-out frame `index` as the field rendered it after training (H, W, 3) float32 in
        [0, 1], display-encoded; None when it was not rendered (train.eval_frames)."""
        path = self.folder / HELDOUT_RGB_DIR / f"{index:06d}.png"
        if not path.is_file():
            return None
        import cv2

        bgr = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        return bgr[..., ::-1].astype(np.float32) / 65535.0

    @property
    def heldout(self) -> list[int]:
        """The frames held out of training (and evaluated)."""
        return list(self.metrics.heldout) if self.metrics is not None else []
