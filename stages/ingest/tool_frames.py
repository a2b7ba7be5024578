"""Which tool mask each kept frame gets: the input's own masks, else the detector's, else none.

One place decides, so the stage, its log and its summary say the same thing about where the
masks came from and how they were read.
"""

from __future__ import annotations

import numpy as np

from endopipe.stages.ingest.config import ToolsConfig
from endopipe.stages.ingest.tool_detect import detect_tools
from endopipe.stages.ingest.tools import polarity_said, read_tool_mask
from endopipe.stages.io.tool_masks import ToolMasks


class FrameTools:
    """Tool masks for the kept frames, and how to say where they came from."""

    def __init__(self, masks: ToolMasks | None, cfg: ToolsConfig) -> None:
        if masks is not None and masks.polarity is not None and cfg.polarity == "auto":
            cfg = cfg.model_copy(update={"polarity": masks.polarity})  # as the data set draws them
        self.masks, self.cfg = masks, cfg
        self.detect = masks is None and cfg.detect == "auto"

    @property
    def active(self) -> bool:
        return self.masks is not None or self.detect

    @property
    def polarity(self) -> str:
        return "detected" if self.masks is None else polarity_said(self.cfg.polarity)

    @property
    def where(self) -> str:
        """'masks/' (given) or 'detected'."""
        if self.masks is None:
            return "detected"
        return f"{self.masks.folder.name}/ ({self.masks.folder})"

    @property
    def said(self) -> str:
        """frames.json's `tools`: 'masks/ (255 = tool)' or 'detected'."""
        return "detected" if self.masks is None else f"{self.masks.folder.name}/ ({self.polarity})"

    def of(
        self, source_index: int, rgb: np.ndarray, fov: np.ndarray, size: tuple[int, int]
    ) -> np.ndarray | None:
        """(H, W) bool, True on a tool; None when there are no tool masks at all. A frame the
        given masks skip has no tool in view."""
        if self.masks is not None:
            path = self.masks.file(source_index)
            if path is None:
                return np.zeros((size[1], size[0]), bool)
            return read_tool_mask(path, size, self.cfg.polarity)
        return detect_tools(rgb, fov, self.cfg) if self.detect else None

    def line(self, shares: list[float]) -> str:
        """The log's line: how many frames, from where, in which polarity, what share."""
        n = sum(s > 0 for s in shares)
        figures = (
            f"{np.mean(shares):.1%} of the pixels on average, {max(shares):.1%} at most: left "
            "out of the photometric loss"
        )
        if self.masks is None:
            return (
                f"tools detected in {n} of {len(shares)} frames (grey metal reaching the edge of "
                f"the view), {figures}; --set ingest.tools.detect=off to keep them"
            )
        return (
            f"tool masks: {len(self.masks.files)} read from {self.masks.folder.name}/ "
            f"({self.polarity}), a tool in {n} of {len(shares)} kept frames, {figures}"
        )
