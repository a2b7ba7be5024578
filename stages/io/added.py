"""What a user brings beside the input (`--right FOLDER --baseline-mm B`, `--depth-prior
FOLDER`), put on the input's source: its stereo pairs and its depth prior, part of its digest.

Why here, below the commands: every place that opens the input (the run, the ingest stage, a
batch job, a recording's windows) must open the same input, or its digest and cache key differ.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

from endopipe.pipeline.errors import InputError
from endopipe.pipeline.stage import CaseInfo
from endopipe.stages.io.depth_prior import open_depth_prior
from endopipe.stages.io.input_source import InputSource
from endopipe.stages.io.name_numbers import file_number
from endopipe.stages.io.right_folder import check_baseline, right_folder_pairs
from endopipe.stages.io.stereo_pairs import StereoPairs


@dataclass(frozen=True)
class AddedInputs:
    """The folders a user gave with the input (None: not given)."""

    right: Path | None = None
    baseline_mm: float | None = None
    depth_prior: Path | None = None

    @classmethod
    def of_case(cls, info: CaseInfo) -> AddedInputs:
        """What case.json recorded the user gave with the input."""
        return cls(
            right=Path(info.right) if info.right else None,
            baseline_mm=info.baseline_mm,
            depth_prior=Path(info.depth_prior) if info.depth_prior else None,
        )

    @property
    def given(self) -> bool:
        return any(v is not None for v in (self.right, self.baseline_mm, self.depth_prior))


def add_inputs(source: InputSource, added: AddedInputs | None) -> InputSource:
    """`source` with the user's right views and depth prior on it (checked: one line each)."""
    if added is None or not added.given:
        return source
    if added.baseline_mm is not None and added.right is None and source.stereo is None:
        raise InputError("--baseline-mm goes with --right FOLDER (the right eye's frames)")
    numbers, count = frame_numbers(source), source.frame_count()
    size = frame_size(source) if added.right or added.depth_prior else None
    if added.right is not None:
        assert size is not None
        source.stereo = user_rig(source, added, numbers, count, size)
    elif added.baseline_mm is not None and source.stereo is not None:
        baseline = check_baseline(added.baseline_mm)
        line = (
            f"--baseline-mm {baseline:g} replaces the {source.stereo.baseline_mm:g} mm the "
            f"input's rig gives ({source.stereo.source})"
        )
        source.stereo = replace_baseline(source.stereo, baseline)
        source.notes.append(line)
    if added.depth_prior is not None:
        assert size is not None
        source.depth_prior = open_depth_prior(added.depth_prior, numbers, count, size)
    return source


def user_rig(
    source: InputSource,
    added: AddedInputs,
    numbers: list[int] | None,
    count: int | None,
    size: tuple[int, int],
) -> StereoPairs:
    """The `--right` folder's pairs; the input's own rig (a reader's) gives the baseline when
    none is given, and is replaced either way, said in `source.notes`."""
    assert added.right is not None
    known = source.stereo
    baseline = added.baseline_mm
    if baseline is None and known is not None:
        baseline = known.baseline_mm
    pairs = right_folder_pairs(added.right, check_baseline(baseline), numbers, count, size)
    if known is not None:
        whose = "--baseline-mm" if added.baseline_mm is not None else f"the rig's ({known.source})"
        source.notes.append(
            f"--right {added.right} replaces the right views the input came with "
            f"({known.source}); baseline {pairs.baseline_mm:g} mm from {whose}"
        )
    return pairs


def replace_baseline(pairs: StereoPairs, baseline_mm: float) -> StereoPairs:
    """The same right views with another baseline (the user's word over the calibration's)."""
    return replace(pairs, baseline_mm=baseline_mm, source=f"{pairs.source}, --baseline-mm")


def frame_numbers(source: InputSource) -> list[int] | None:
    """The number each frame's file carries, by source_index (an image list's names); None for
    a video, or names without distinct numbers, whose frames are numbered by position."""
    files = getattr(source, "files", None)
    if not files:
        return None
    numbers = [file_number(f) for f in files]
    if any(n is None for n in numbers) or len(set(numbers)) != len(numbers):
        return None
    return [int(n) for n in numbers if n is not None]


def frame_size(source: InputSource) -> tuple[int, int]:
    """(width, height) of the frames as read: an image list's common size, else the first
    frame's (a video's, decoded once)."""
    size = getattr(source, "size", None)
    if size is not None:
        return tuple(size)  # type: ignore[return-value]
    first = next(iter(source.frames()), None)
    if first is not None:
        return first.rgb.shape[1], first.rgb.shape[0]
    raise InputError(f"{source.path} holds no frame")
