"""A small synthetic stereo Hamlyn sequence, written as `endopipe synth --layout hamlyn
--stereo` writes it (image01/, image02/, depth01/, intrinsics.txt, extrinsics.txt, exact gt/)."""

from __future__ import annotations

from functools import partial
from pathlib import Path

from endopipe.synth import Layout, SynthConfig, SynthSummary, generate_case
from endopipe.synth.hamlyn_sink import HamlynSink

BASELINE_MM = 5.0


def write_stereo_hamlyn(
    seq: Path, seed: int = 1, frames: int = 4, width: int = 320, height: int = 256, **extra
) -> SynthSummary:
    """The sequence in `seq` (a rectifiedNN folder); `extra`: more SynthConfig fields."""
    cfg = SynthConfig(
        seed=seed,
        frames=frames,
        width=width,
        height=height,
        stereo_baseline_mm=BASELINE_MM,
        **extra,
    )
    layout = Layout("hamlyn", partial(HamlynSink, baseline_mm=BASELINE_MM), takes_right=True)
    return generate_case(seq, cfg, layout=layout)
