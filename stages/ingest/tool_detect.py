"""Surgical tools found in a frame when the input gives no masks: a conservative guess.

Instruments are grey metal (low saturation, lit, often specular) and enter the view from its
edge, so a tool is a large low-saturation region that reaches the border of the field of view.
Tissue is red or pink (saturated); a pale patch in the middle of the view, a small highlight or
a pale region with a warm cast (fat, a wall washed out by the light) is not taken. Measured
before it was trusted: docs/experiments.md.
"""

from __future__ import annotations

import cv2
import numpy as np

from endopipe.stages.ingest.config import ToolsConfig

#: How far in from the field of view's edge a region must reach to count as entering the view.
BORDER_FRAC = 0.03


def detect_tools(rgb: np.ndarray, fov: np.ndarray, cfg: ToolsConfig) -> np.ndarray:
    """(H, W) bool, True on what looks like an instrument."""
    h, w = rgb.shape[:2]
    hsv = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2HSV)
    inside = fov > 0
    grey = (hsv[..., 1] <= cfg.max_saturation) & (hsv[..., 2] >= cfg.min_value) & inside
    r = max(1, round(0.01 * min(h, w)))
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    grey = cv2.morphologyEx(grey.astype(np.uint8), cv2.MORPH_CLOSE, kernel)
    grey = cv2.morphologyEx(grey, cv2.MORPH_OPEN, kernel)
    band = max(2, round(BORDER_FRAC * min(h, w)))
    core = cv2.erode(inside.astype(np.uint8), np.ones((3, 3), np.uint8), iterations=band) > 0
    edge = inside & ~core
    edge[[0, -1], :] = edge[:, [0, -1]] = True
    n, labels, stats, _ = cv2.connectedComponentsWithStats(grey, connectivity=8)
    keep = np.zeros(n, bool)
    at_edge = np.unique(labels[edge & (labels > 0)])
    keep[at_edge] = stats[at_edge, cv2.CC_STAT_AREA] >= cfg.min_area * h * w
    # Metal under the scope's white light is neutral or cool; pale tissue (fat, a gallbladder,
    # a wall washed out by the light) keeps a warm cast: red above blue.
    cast = rgb[..., 2].astype(np.float64) - rgb[..., 0]
    inner = grey > 0
    sums = np.bincount(labels[inner], weights=cast[inner], minlength=n)
    counts = np.maximum(np.bincount(labels[inner], minlength=n), 1)
    keep &= sums / counts >= cfg.min_blue_minus_red
    tool = keep[labels] & inside
    # A grey region filling most of the view is the scene (a grey phantom, a blank frame).
    if tool.sum() > cfg.max_share * max(inside.sum(), 1):
        return np.zeros_like(tool)
    grow = round(cfg.grow * min(h, w))
    if grow > 0 and tool.any():  # the rim: the shaft's shaded edge, a thin jaw
        disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * grow + 1, 2 * grow + 1))
        tool = (cv2.dilate(tool.astype(np.uint8), disk) > 0) & inside
    return tool
