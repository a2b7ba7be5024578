"""`endopipe synth`: a synthetic lumen case with exact ground truth, behind a progress bar.
The generator itself is the synth package; this module checks the settings and reports."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from endopipe.commands.terminal import console, out
from endopipe.pipeline.errors import EndopipeError

if TYPE_CHECKING:
    from endopipe.synth import Layout, SynthConfig, SynthSummary

#: --layout: endopipe's case folder, EndoNeRF's layout instead of its frames, or both (EndoNeRF's
#: in the case's endonerf/ folder).
LAYOUTS = ("endopipe", "endonerf", "both")


def synth_case(
    out_dir: Path,
    *,
    seed: int,
    frames: int,
    width: int,
    height: int,
    shape: str,
    lens: str,
    fov_diag: float | None,
    vignetting: float,
    recording: dict | None = None,
    motion: dict | None = None,
    layout: str = "endopipe",
) -> None:
    """Validate the settings (one line naming the bad one), write the case, say what it is."""
    from pydantic import ValidationError

    from endopipe.pipeline.runner import ensure_writable
    from endopipe.synth import SynthConfig

    try:
        cfg = SynthConfig(
            seed=seed,
            frames=frames,
            width=width,
            height=height,
            shape=shape,
            lens=lens,
            fov_diag_deg=fov_diag,
            vignetting=vignetting,
            **(recording or {}),
            **(motion or {}),
        )
    except ValidationError as e:
        err = e.errors()[0]
        raise EndopipeError(f"synth {'.'.join(map(str, err['loc']))}: {err['msg']}") from None
    if layout not in LAYOUTS:
        raise EndopipeError(f"synth layout: {layout} is none of {', '.join(LAYOUTS)}")
    ensure_writable(out_dir.parent if out_dir.parent != Path("") else Path("."))
    summary = write_synth(out_dir, cfg, other_layout(layout))
    moving = ""
    if summary.deform != "none":
        moving = f", {summary.deform} {summary.deform_amplitude:g}"
        moving += ", a tool in view (masks/)" if summary.tool else ""
    out.print(
        f"wrote {summary.frames} frames ({shape}, path {summary.path_length_mm:.1f} mm, "
        f"mean radius {summary.mean_radius_mm:.1f} mm{moving}) to {out_dir} in "
        f"{summary.seconds:.1f} s"
    )


def other_layout(layout: str) -> Layout | None:
    """EndoNeRF's layout, written by the export library as the frames are rendered."""
    if layout == "endopipe":
        return None
    from endopipe.export.endonerf_sink import EndoNerfSink
    from endopipe.synth import Layout

    return Layout("endonerf", EndoNerfSink, subfolder="endonerf" if layout == "both" else "")


def write_synth(out_dir: Path, cfg: SynthConfig, layout: Layout | None = None) -> SynthSummary:
    """Generate the case with a transient progress bar (frames rendered so far)."""
    from rich.progress import Progress

    from endopipe.synth import generate_case

    with Progress(console=console, transient=True) as bar:
        task = bar.add_task("synth", total=cfg.frames)
        return generate_case(
            out_dir, cfg, progress=lambda i, n: bar.update(task, completed=i + 1), layout=layout
        )
