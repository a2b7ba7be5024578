"""One SfM for a short recording: when its keyframes are few enough for one SfM to cost no more
than the windows' own (`RecordingOptions.one_sfm_up_to`), the recording's own case is posed and
its lumen fitted once, and every window takes its stretch of both; the windows then split only
the field's work.

Why: a window's own SfM sees a short stretch. C3VD's 75 frames in two windows of 45: the
second window's poses alone lie 5.41% of the path from the whole clip's, the joined path 3.57%,
and each window fits a straight, wide tube to its stretch (depth SSI-AbsRel 0.205 against the
whole clip's 0.114). It costs no more: endo.mp4's 125 keyframes in four windows of 39 are
posed in 54 s this way, 60 s each window alone. Longer recordings keep a SfM per window
(poses cost n^1.57).

The recording's own case runs as one task on the run's executor, as a window would (on a
cluster, not in the driver). The shared folder, `<case>/one_sfm/<key>/`, is named after the
poses and centerline stages' cache keys, so the windows' settings (and so their cache keys)
change when those re-run.
"""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.markup import escape

from endopipe.jobs.rows import CaseRow
from endopipe.pipeline.runner import Pipeline

ONE_SFM_DIR = "one_sfm"


def pose_once(pipe: Pipeline, case_dir: Path, row: CaseRow, console: Console) -> Path | None:
    """After the recording's own case ran to its lumen prior (`row`, a task on the run's
    executor like a window), what the windows take from it; None (with a line saying so)
    when that failed: each window then poses its own stretch."""
    if row.status != "ok":
        console.print(
            f"[yellow]one SfM over the recording failed ({escape(row.reason)}); each window "
            "poses its own stretch[/yellow]"
        )
        return None
    ran = f"ran {'+'.join(row.stages_ran)}" if row.stages_ran else "cached"
    console.print(f"[green]✓[/green] one SfM over the recording's keyframes, {ran}")
    keys = [pipe.manifest(case_dir, s).key for s in ("poses", "centerline")]  # type: ignore[union-attr]
    folder = case_dir / ONE_SFM_DIR / hashlib.sha256("".join(keys).encode()).hexdigest()[:16]
    if not folder.is_dir():
        _write(pipe, case_dir, folder)
    for old in (case_dir / ONE_SFM_DIR).iterdir():
        if old != folder:
            shutil.rmtree(old, ignore_errors=True)
    return folder


def stretch_cuts(pipe: Pipeline, case_dir: Path) -> dict[int, str]:
    """Where the one SfM hangs together by few points (`stages/poses/links.py`): the keyframe
    (source_index) that starts each stretch after the first, and why. Windows never straddle
    such a link: a stretch glued on by a few points may be turned against the rest."""
    from endopipe.stages.poses.links import cutting_links

    verdict = pipe.view(case_dir, "poses").verdict()
    if verdict is None or not verdict.weak_links:
        return {}
    source_of = {f.index: f.source_index for f in pipe.view(case_dir, "ingest").frames}
    registered = np.array([f.index for f in verdict.frames if f.status != "unregistered"])
    return {
        source_of[link.before]: (
            f"the one SfM holds keyframes {source_of[link.after]} and {source_of[link.before]} "
            f"together by {link.points} points ({link.share:.0%} of those seen near): "
            "posed apart"
        )
        for link in cutting_links(registered, verdict.weak_links)
    }


def window_settings(folder: Path) -> dict[str, dict]:
    """What a window's settings take from the shared folder: its poses (by input frame) and
    the recording's lumen."""
    return {
        "poses": {"source": "file", "file": str(folder / "sparse")},
        "centerline": {"given_prior": str(folder / "prior")},
    }


def _write(pipe: Pipeline, case_dir: Path, folder: Path) -> None:
    """The recording's COLMAP model with its images named by input frame (`source-000123.png`,
    so a window's poses stage matches them by that number) and its lumen prior with the camera
    centres it was fitted among; written whole, then renamed into place."""
    import pycolmap  # cv2 is already imported through the `endopipe.stages` package

    from endopipe.stages.centerline.given import write_given_prior
    from endopipe.stages.io.colmap_model import keep_images

    ingest = pipe.view(case_dir, "ingest")
    poses = pipe.view(case_dir, "poses")
    source_of = {f.index: f.source_index for f in ingest.frames}
    tmp = folder.with_name(f".{folder.name}.tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    (tmp / "sparse").mkdir(parents=True)
    rec = pycolmap.Reconstruction(str(poses.sparse_dir))
    names = {name: f"source-{source_of[i]:06d}.png" for name, i in ingest.index_by_name().items()}
    keep_images(rec, names)
    rec.write_text(str(tmp / "sparse"))
    centres = {source_of[i]: c2w[:3, 3] for i, c2w in poses.c2w.items()}
    write_given_prior(tmp / "prior", pipe.view(case_dir, "centerline").prior(), centres)
    tmp.rename(folder)
