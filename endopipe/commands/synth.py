"""`endopipe synth`: a synthetic lumen case with exact ground truth, behind a progress bar.
The generator itself is the synth package; this module checks the settings and reports."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from endopipe.commands.terminal import console, out
from endopipe.pipeline.errors import EndopipeError

if TYPE_CHECKING:
    from endopipe.synth import SynthConfig, SynthSummary


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
        )
    except ValidationError as e:
        err = e.errors()[0]
        raise EndopipeError(f"synth {'.'.join(map(str, err['loc']))}: {err['msg']}") from None
    ensure_writable(out_dir.parent if out_dir.parent != Path("") else Path("."))
    summary = write_synth(out_dir, cfg)
    out.print(
        f"wrote {summary.frames} frames ({shape}, path {summary.path_length_mm:.1f} mm, "
        f"mean radius {summary.mean_radius_mm:.1f} mm) to {out_dir} in {summary.seconds:.1f} s"
    )


def write_synth(out_dir: Path, cfg: SynthConfig) -> SynthSummary:
    """Generate the case with a transient progress bar (frames rendered so far)."""
    from rich.progress import Progress

    from endopipe.synth import generate_case

    with Progress(console=console, transient=True) as bar:
        task = bar.add_task("synth", total=cfg.frames)
        return generate_case(out_dir, cfg, progress=lambda i, n: bar.update(task, completed=i + 1))
