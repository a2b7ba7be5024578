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
#: in the case's endonerf/ folder); a rectified Hamlyn sequence (hamlyn) or EDaM's copy (edam).
LAYOUTS = ("endopipe", "endonerf", "both", "hamlyn", "edam", "c3vd", "scared", "stereomis")
#: The layouts of laparoscopic data sets: their scene, unless --shape names one, is the cavity,
#: whose walls (12-33 mm) lie at a laparoscope's working distance; a colon's near wall (8 mm)
#: would put a third of the width out of a 5 mm rig's right eye.
LAPAROSCOPIC_LAYOUTS = ("hamlyn", "scared", "stereomis")
#: --stereo: the right eye's baseline, mm (Hamlyn's rig: about 5).
STEREO_BASELINE_MM = 5.0


def synth_case(
    out_dir: Path,
    *,
    seed: int,
    frames: int,
    width: int,
    height: int,
    shape: str | None,
    lens: str,
    fov_diag: float | None,
    vignetting: float,
    recording: dict | None = None,
    motion: dict | None = None,
    layout: str = "endopipe",
    stereo: bool = False,
) -> None:
    """Validate the settings (one line naming the bad one), write the case, say what it is.
    An unset `shape` is the layout's own scene (`LAPAROSCOPIC_LAYOUTS`)."""
    from pydantic import ValidationError

    from endopipe.pipeline.runner import ensure_writable
    from endopipe.synth import SynthConfig

    if shape is None:
        shape = "cavity" if layout in LAPAROSCOPIC_LAYOUTS else "colon"
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
            stereo_baseline_mm=STEREO_BASELINE_MM if stereo else None,
        )
    except ValidationError as e:
        err = e.errors()[0]
        raise EndopipeError(f"synth {'.'.join(map(str, err['loc']))}: {err['msg']}") from None
    if layout not in LAYOUTS:
        raise EndopipeError(f"synth layout: {layout} is none of {', '.join(LAYOUTS)}")
    sink = other_layout(layout, cfg.stereo_baseline_mm, cfg.lens)
    if stereo and (sink is None or not sink.takes_right):
        raise EndopipeError(
            f"synth --stereo: the {layout} layout has no right eye (hamlyn, scared, stereomis and "
            "endonerf have one)"
        )
    ensure_writable(out_dir.parent if out_dir.parent != Path("") else Path("."))
    summary = write_synth(out_dir, cfg, sink)
    moving = ""
    if summary.deform != "none":
        moving = f", {summary.deform} {summary.deform_amplitude:g}"
        moving += ", a tool in view (masks/)" if summary.tool else ""
    out.print(
        f"wrote {summary.frames} frames ({shape}, path {summary.path_length_mm:.1f} mm, "
        f"mean radius {summary.mean_radius_mm:.1f} mm{moving}) to {out_dir} in "
        f"{summary.seconds:.1f} s"
    )


def other_layout(
    layout: str, baseline_mm: float | None = None, lens: str = "pinhole"
) -> Layout | None:
    """EndoNeRF's layout, written by the export library as the frames are rendered (its depth/
    matched from a right eye at `baseline_mm` when given); Hamlyn's and EDaM's, by the synth
    library's sinks (Hamlyn's with the right eye at `baseline_mm`); C3VD's with its own
    calibration folder when the `lens` is C3VD's."""
    if layout == "endopipe":
        return None
    if layout in ("hamlyn", "edam"):
        return data_set_layout(layout, baseline_mm)
    if layout in ("c3vd", "scared", "stereomis"):
        return lens_layout(layout, baseline_mm, lens)
    from functools import partial

    from endopipe.export.endonerf_sink import EndoNerfSink
    from endopipe.synth import Layout

    return Layout(
        "endonerf",
        partial(EndoNerfSink, baseline_mm=baseline_mm),
        subfolder="endonerf" if layout == "both" else "",
        takes_right=baseline_mm is not None,
    )


def data_set_layout(layout: str, baseline_mm: float | None) -> Layout:
    """A data set's own layout in place of endopipe's frames (gt/ kept beside it)."""
    from functools import partial

    from endopipe.synth import Layout
    from endopipe.synth.edam_sink import EdamSink
    from endopipe.synth.hamlyn_sink import HamlynSink

    if layout == "edam":
        return Layout("edam", EdamSink)
    return Layout("hamlyn", partial(HamlynSink, baseline_mm=baseline_mm), takes_right=True)


def lens_layout(layout: str, baseline_mm: float | None, lens: str = "pinhole") -> Layout:
    """C3VD's layout (its calibration and model mesh), a SCARED keyframe or a StereoMIS sequence
    (its right eye at `baseline_mm` when given), in place of endopipe's frames (gt/ kept)."""
    from functools import partial

    from endopipe.synth import Layout
    from endopipe.synth.c3vd_sink import C3VDSink
    from endopipe.synth.scared_sink import ScaredSink
    from endopipe.synth.stereomis_sink import StereoMISSink

    if layout == "c3vd":
        return Layout("c3vd", partial(C3VDSink, shipped_lens=lens == "c3vd"))
    sink = StereoMISSink if layout == "stereomis" else ScaredSink
    return Layout(layout, partial(sink, baseline_mm=baseline_mm), takes_right=True)


def write_synth(out_dir: Path, cfg: SynthConfig, layout: Layout | None = None) -> SynthSummary:
    """Generate the case with a transient progress bar (frames rendered so far)."""
    from rich.progress import Progress

    from endopipe.synth import generate_case

    with Progress(console=console, transient=True) as bar:
        task = bar.add_task("synth", total=cfg.frames)
        return generate_case(
            out_dir, cfg, progress=lambda i, n: bar.update(task, completed=i + 1), layout=layout
        )
