"""A case's depth error on the tissue a tool covers in some frame (the field must infer it from
the frames where it shows) and elsewhere, on tissue only (each frame's own tool left out, as the
depth stage scores it): AbsRel as published (unscaled) and after each frame's median scale.

Run: `.venv/bin/python scripts/tool_path_depth.py W/runs/CASE [W2/runs/CASE ...]` on cases with
tool masks and ground-truth depth (`endopipe bench --case pull_still_endonerf`). A diagnosis,
not a test.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from endopipe.cli import build_pipeline
from endopipe.stages.io.ground_truth import depth_of_frame


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("cases", type=Path, nargs="+")
    args = ap.parse_args()
    views = {s.name: s.View for s in build_pipeline().stages}
    for case in args.cases:
        ingest = views["ingest"](case / "01_ingest")
        depth = views["depth"](case / "05_depth")
        gt = ingest.ground_truth()
        tools = {i: ingest.tool_mask(i) for i in ingest.indices}
        ever = np.zeros((ingest.height, ingest.width), bool)
        for tool in tools.values():
            if tool is not None:
                ever |= tool
        errors: dict[str, list[np.ndarray]] = {"path": [], "elsewhere": []}
        scaled: dict[str, list[np.ndarray]] = {"path": [], "elsewhere": []}
        scales = []
        for i in ingest.indices:
            ours, truth = depth.depth(i), depth_of_frame(gt, ingest.frame(i))
            if truth is None:
                continue
            if truth.shape != ours.shape:
                truth = cv2.resize(truth, ours.shape[::-1], interpolation=cv2.INTER_NEAREST)
            tool = tools[i] if tools[i] is not None else np.zeros_like(ever)
            ok = (ours > 0) & (truth > 0) & ~tool & (ingest.mask(i) > 127)
            s = np.median(truth[ok]) / np.median(ours[ok])
            scales.append(s)
            for name, m in (("path", ok & ever), ("elsewhere", ok & ~ever)):
                errors[name].append(np.abs(ours[m] - truth[m]) / truth[m])
                scaled[name].append(np.abs(s * ours[m] - truth[m]) / truth[m])
        line = [f"{case}:"]
        for name in errors:
            e, es = np.concatenate(errors[name]), np.concatenate(scaled[name])
            line.append(f"{name} ({len(e)} px): {e.mean():.4f} unscaled, {es.mean():.4f} scaled;")
        line.append(f"median scale a frame {np.median(scales):.4f}")
        print(" ".join(line))


if __name__ == "__main__":
    main()
