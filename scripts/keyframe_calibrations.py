"""A stereo pair alone, its calibration as shipped and spoiled: how close the rig's depth comes to
the truth when the calibration is turned or stated for another image size.

    .venv/bin/python scripts/keyframe_calibrations.py [--size 640x512] [--seed 3]
        [--keyframe FOLDER] [--workdir DIR]

A synthetic SCARED keyframe (`endopipe synth --layout scared --stereo`, its video removed: the
two images, the calibration and left_depth_map.tiff, as SCARED ships a keyframe) is run with
`endopipe run --until depth`, no flags, as it is and as copies whose calibration says the right
eye is turned (about the rows' axis: a tilt; plus the optical axis: a roll; about the columns'
axis: a toe-in) or whose matrices are stated for half the image size. Each row: what ingest's
rig check said it found, the depth's AbsRel against the truth with no scaling, and its coverage
of the truth's pixels. `--keyframe` runs a real keyframe folder the same way (its own rows only).
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
from pathlib import Path

import endopipe.stages  # noqa: F401  (cv2 first)
from endopipe.cli import main
from endopipe.commands.synth import other_layout
from endopipe.synth import SynthConfig, generate_case
from endopipe.synth.scared_sink import spoil_calibration

#: name -> (rotation vector of the turn in degrees, matrices stated for half the size)
VARIANTS: dict[str, tuple[tuple[float, float, float], bool]] = {
    "as shipped": ((0.0, 0.0, 0.0), False),
    "tilted 2 deg": ((2.0, 0.0, 0.0), False),
    "tilted 2 deg, rolled 0.5": ((2.0, 0.0, 0.5), False),
    "toe-in 1 deg": ((0.0, 1.0, 0.0), False),
    "stated for half the size": ((0.0, 0.0, 0.0), True),
}


def spoiled(keyframe: Path, out: Path, turn_deg: tuple[float, float, float], half: bool) -> Path:
    """A copy of `keyframe` with its calibration spoiled (synth/scared_sink.py)."""
    shutil.copytree(keyframe, out)
    spoil_calibration(out, turn_deg, half)
    return out


def synthetic_keyframe(folder: Path, size: tuple[int, int], seed: int) -> Path:
    out = folder / "keyframe_1"
    cfg = SynthConfig(seed=seed, frames=2, width=size[0], height=size[1], stereo_baseline_mm=5.0)
    generate_case(out, cfg, layout=other_layout("scared", 5.0))
    shutil.rmtree(out / "data")
    shutil.rmtree(out / "gt")  # scored against left_depth_map.tiff, as a real keyframe
    return out


def scored(keyframe: Path, workdir: Path) -> tuple[str, float | None, float | None]:
    """(the rig check's line, unscaled AbsRel, coverage) of one run to depth."""
    code = main(["run", str(keyframe), "--workdir", str(workdir), "--until", "depth", "--quiet"])
    if code != 0:
        return f"exit {code}", None, None
    case = workdir / keyframe.name
    frames = json.loads((case / "01_ingest" / "frames.json").read_text())
    rig = (frames.get("stereo") or {}).get("rig") or {}
    metrics = json.loads((case / "05_depth" / "metrics.json").read_text())
    unscaled = metrics.get("unscaled") or {}
    return rig.get("said", "not checked"), unscaled.get("abs_rel"), unscaled.get("coverage")


def main_cli() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="640x512", help="the synthetic keyframe's WxH")
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--keyframe", type=Path, help="a real keyframe folder, run as it is")
    ap.add_argument("--workdir", type=Path, help="keep the runs here (default: a temporary one)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        root = args.workdir or Path(tmp)
        if args.keyframe is not None:
            cases = {"as shipped": args.keyframe.resolve()}
        else:
            w, h = (int(v) for v in args.size.split("x"))
            base = synthetic_keyframe(root / "input", (w, h), args.seed)
            cases = {
                name: base
                if name == "as shipped"
                else spoiled(base, root / f"v{i}" / base.name, *v)
                for i, (name, v) in enumerate(VARIANTS.items())
            }
        print("| calibration | AbsRel, no scaling | coverage | the rig check |")
        print("|---|---|---|---|")
        for i, (name, folder) in enumerate(cases.items()):
            said, abs_rel, coverage = scored(folder, root / f"w{i}")
            a = "-" if abs_rel is None else f"{abs_rel:.4f}"
            c = "-" if coverage is None else f"{coverage:.3f}"
            print(f"| {name} | {a} | {c} | {said} |", flush=True)


if __name__ == "__main__":
    main_cli()
