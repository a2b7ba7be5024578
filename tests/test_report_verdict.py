"""The poses' verdict on the report: a doubtful verdict is shown with its reasons,
the mapper kept and what became of the other, and the doubtful frames; ok, not assessed and
an older folder without a verdict say so. Built on the hand-made case (no stage runs)."""

from __future__ import annotations

import html
import re
from pathlib import Path

import pytest

from endopipe.stages.poses.verdict import FrameVerdict, PoseVerdict
from endopipe.stages.report.config import ReportConfig
from endopipe.stages.report.load import load_case
from endopipe.stages.report.sections import ReportInfo, section_poses, section_summary
from endopipe.stages.report.sections.pose_verdict import OLD_FOLDER, frame_table
from tests.handmade_case import N_FRAMES, UNREGISTERED, make_case

DRIFT = "scale drift: the scene's depth changes 7.3x along the path (> 4x)"
DISAGREE = "the two mappers disagree by 12.4% of the path (> 5%)"
GLOBAL_WHY = "sound on its own; 12.4% of the path from the kept poses"


def doubtful_verdict() -> PoseVerdict:
    """Frames 1 and 2 doubtful (two reasons for 2), frame UNREGISTERED has no pose."""
    frames = [FrameVerdict(index=i, status="ok", points=300) for i in range(N_FRAMES)]
    frames[1] = FrameVerdict(
        index=1, status="doubtful", reasons=["sees 12 triangulated points (< 40)"], points=12
    )
    frames[2] = FrameVerdict(
        index=2,
        status="doubtful",
        reasons=["jumps 9.1x the median move", "reprojection error 3.20 px (> 2.0)"],
        points=150,
        reprojection_px=3.2,
        disagreement_pct=14.25,
    )
    frames[UNREGISTERED] = FrameVerdict(index=UNREGISTERED, status="unregistered")
    return PoseVerdict(
        status="doubtful",
        reasons=[DRIFT, DISAGREE],
        mapper="incremental",
        depth_drift=7.31,
        disagreement_pct=12.4,
        others={"global": GLOBAL_WHY},
        frames=frames,
    )


def poses_case(tmp_path: Path) -> Path:
    """The hand-made case up to its poses (with the whole summaries the stages write)."""
    return make_case(tmp_path, gt=False, stages=("ingest", "poses"))


def sections(tmp_path: Path, verdict: PoseVerdict | None) -> tuple[str, str]:
    """(summary, poses) sections' HTML of a hand-made case whose 02_poses holds `verdict`."""
    case = poses_case(tmp_path)
    if verdict is not None:
        verdict.write(case / "02_poses" / "verdict.json")
    folders = {"ingest": case / "01_ingest", "poses": case / "02_poses"}
    data = load_case(case, folders, ReportConfig(max_runs=0))
    info = ReportInfo()
    return section_summary(data, info), section_poses(data, info) or ""


def visible(fragment: str) -> str:
    fragment = re.sub(r"<(pre|iframe)\b.*?</\1>", " ", fragment, flags=re.S)
    return html.unescape(re.sub(r"\s+", " ", re.sub(r"<[^>]+>", " ", fragment))).strip()


def warnings(fragment: str) -> list[str]:
    """The red warning paragraphs (class exactly 'verdict'), as text."""
    return [visible(p) for p in re.findall(r'<p class="verdict">(.*?)</p>', fragment, re.S)]


def test_a_doubtful_verdict_is_a_warning_with_its_reasons_and_frames(tmp_path: Path) -> None:
    summary, poses = sections(tmp_path, doubtful_verdict())
    headline = f"Poses: doubtful — {DRIFT}; {DISAGREE}"
    assert warnings(poses) == [headline]
    assert headline in warnings(summary)  # on the first screen too
    text = visible(poses)
    assert "Mapper kept incremental" in text
    assert f"global mapper (not kept) {GLOBAL_WHY}" in text
    assert "Mappers' disagreement 12.4 % of the path" in text
    assert "Depth drift 7.31×" in text
    assert f"Doubtful frames 2 of {N_FRAMES - 1} registered: 1-2" in text
    # the per-frame table: each doubtful frame with its reasons and evidence, nothing else
    table = visible(re.search(r"<table class=\"grid metrics\">.*?</table>", poses, re.S)[0])
    assert "1 sees 12 triangulated points (< 40) 12" in table
    assert "2 jumps 9.1x the median move; reprojection error 3.20 px (> 2.0) 150 3.2 px" in table
    assert "14.25 % of the path" in table
    assert not re.search(rf"\b{UNREGISTERED} —", table)
    assert "red crosses: doubtful poses" in text  # marked on the trajectory


def test_an_ok_verdict_is_no_warning(tmp_path: Path) -> None:
    verdict = doubtful_verdict()
    verdict.status, verdict.reasons = "ok", []
    for f in verdict.frames:
        if f.status == "doubtful":
            f.status, f.reasons = "ok", []
    summary, poses = sections(tmp_path, verdict)
    assert warnings(poses) == [] and warnings(summary) == []
    assert '<p class="verdict ok"><b>Poses: ok</b></p>' in poses
    assert f"Doubtful frames 0 of {N_FRAMES - 1} registered" in visible(poses)
    assert "red crosses" not in poses


@pytest.mark.parametrize(
    ("verdict", "said"),
    [
        (
            PoseVerdict(status="not assessed", reasons=["poses from gt"], mapper="gt"),
            "Poses: not assessed — poses from gt",
        ),
        (None, f"Poses: {OLD_FOLDER}"),
    ],
)
def test_no_judgement_says_why(tmp_path: Path, verdict: PoseVerdict | None, said: str) -> None:
    summary, poses = sections(tmp_path, verdict)
    assert said in visible(poses)
    assert warnings(poses) == [] and warnings(summary) == []
    assert "Mapper kept" not in visible(poses)


def test_long_lists_of_doubtful_frames_stop_at_twenty_rows() -> None:
    frames = [
        FrameVerdict(index=i, status="doubtful", reasons=[f"reason {i}"]) for i in range(3, 30)
    ]
    table = frame_table(frames)
    assert table.count("<tr>") - 1 == 20  # the head's row, then 20 frames
    assert "reason 22" in table and "reason 23" not in table
    assert "and 7 more doubtful frame(s): 23-29" in visible(table)


def test_an_unreadable_verdict_costs_its_block_only(tmp_path: Path) -> None:
    case = poses_case(tmp_path)
    (case / "02_poses" / "verdict.json").write_text('{"status": "maybe"}')
    folders = {"ingest": case / "01_ingest", "poses": case / "02_poses"}
    data = load_case(case, folders, ReportConfig(max_runs=0))
    poses = section_poses(data, ReportInfo()) or ""
    assert "02_poses/verdict.json unreadable" in visible(poses)
    assert "<figure" in poses and "Poses and centre line" in poses  # the rest is still there
