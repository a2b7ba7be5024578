"""The whole pipeline on a tiny synthetic colon, through the CLI: caching, staleness, resume."""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path

import pytest

from endopipe.cli import build_pipeline, main
from tests.conftest import TINY, TinyRun

# Share of the lens's pixels with no depth on the tiny colon: measured 1.1% (0.1% for the
# spread, depth.max_spread); 0.60% when the rays past the fine bake are volume-rendered
# (depth.far=field), 2.6% when the far bake does not continue a thin wall's ramp.
UNKNOWN_AT_MOST = 0.02


def last_record(case: Path) -> dict:
    return json.loads(sorted((case / "runs").glob("*.json"))[-1].read_text())


def statuses(case: Path) -> dict[str, str]:
    return {s["stage"]: s["status"] for s in last_record(case)["stages"]}


@pytest.fixture(scope="module")
def first_run(tiny_run: TinyRun, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, float]:
    """The session's tiny run (conftest), copied: these tests re-run and change it."""
    wd = tmp_path_factory.mktemp("wd")
    case = Path(shutil.copytree(tiny_run.case, wd / tiny_run.case.name))
    return case, tiny_run.wall_s


def rerun(case: Path, *extra: str) -> None:
    args = ["run", last_record(case)["input"], "--workdir", str(case.parent), "--quiet", *TINY]
    args += extra
    assert main(args) == 0


def test_every_stage_ran_and_wrote_its_contract(first_run: tuple[Path, float]) -> None:
    case, _ = first_run
    names = [s.name for s in build_pipeline().stages]
    assert statuses(case) == {n: "ran" for n in names}
    frames = json.loads((case / "01_ingest" / "frames.json").read_text())
    assert len(frames["frames"]) >= 12 and frames["intrinsics"]["width"] == 160
    assert frames["frames"][0]["source_index"] == 0
    cameras = json.loads((case / "02_poses" / "cameras.json").read_text())
    assert cameras["metric"] and sum(f["registered"] for f in cameras["frames"]) >= 14
    depth = json.loads((case / "05_depth" / "metrics.json").read_text())
    # a 600-step NeRF on 16 tiny 160x128 frames. With one torch thread and single-threaded COLMAP
    # matching two runs agree to the digit: AbsRel 0.139, δ1 0.835, mesh Chamfer 39.4% of the
    # radius with λ_smooth 0.01 (0.147, 0.807, 39.7% with 0.05). The prior from 342 sparse points
    # sits 41% of the radius off-centre, and the field comes out 13% short overall; runs with
    # other poses gave AbsRel 0.14-0.16, δ1 0.78-0.84, Chamfer 9-40%. Bounded, not paper-grade
    # (the bench measures that): the bounds catch a wrong scale, a broken prior or a missing
    # surface.
    assert depth["median_scaled"]["abs_rel"] < 0.2, depth["median_scaled"]
    assert depth["median_scaled"]["delta1"] > 0.7, depth["median_scaled"]
    # Every ray in a closed synthetic tube meets a wall: few pixels may be left unknown, and
    # the report says how many and why.
    summary = json.loads((case / "05_depth" / "manifest.json").read_text())["summary"]
    assert 0 <= summary["hazy_share"] <= summary["unknown_share"] < UNKNOWN_AT_MOST, summary
    # Every depth map has its views map; the pixels other views agree with hold the better
    # depth (in a closed tube the few pixels no other view sees are its far ends and rims).
    depth_files = sorted(p.name for p in (case / "05_depth" / "depth").glob("*.npy"))
    assert sorted(p.name for p in (case / "05_depth" / "views").glob("*.npy")) == depth_files
    assert (
        summary["seen_again_share"] + summary["one_view_share"]
        <= 1.0 + 1e-9 - summary["unknown_share"]
    )
    # The pixels other views confirm meet the map's bound and cover most of it. Whether they
    # beat the rest is not asked here: the rest is 2% of this tiny tube's pixels and swings with
    # the machine (AbsRel 0.0805 against 0.0802 on one, 0.0807 against 0.0716 on another of the
    # same kind, 0.0800 against 0.0539 on a third); tests/test_depth_support.py tells a right
    # views map from a wrong one on a wall with its truth.
    by = depth["by_support"]
    assert by["seen_again"]["abs_rel"] < 0.2 and by["seen_again"]["coverage"] > 0.9, by
    mesh = json.loads((case / "06_mesh" / "metrics.json").read_text())
    assert mesh["evaluated"] and mesh["chamfer_pct_radius"] < 60, mesh
    report = (case / "07_report" / "report.html").read_text()
    assert "<html" in report.lower() and len(report) > 10_000
    assert "No depth (unknown)" in report
    # geometry auto: a signed distance over a cavity prior only; the report says which.
    prior = json.loads((case / "03_centerline" / "manifest.json").read_text())["summary"]
    nerf = json.loads((case / "04_nerf" / "manifest.json").read_text())["summary"]
    assert nerf["geometry"] == ("sdf" if prior["kind"] == "cavity" else "density"), prior["kind"]
    assert "Geometry" in report


def test_second_run_is_all_cached_and_fast(first_run: tuple[Path, float]) -> None:
    case, first_wall = first_run
    t0 = time.perf_counter()
    rerun(case)
    second = time.perf_counter() - t0
    assert set(statuses(case).values()) == {"cached"}
    assert second < 0.1 * first_wall, (second, first_wall)


def test_config_change_reruns_that_stage_and_downstream_only(first_run: tuple[Path, float]) -> None:
    case, _ = first_run
    rerun(case, "--set", "mesh.smooth_iterations=2")
    st = statuses(case)
    assert st["mesh"] == "ran" and st["report"] == "ran"
    assert all(v == "cached" for k, v in st.items() if k not in ("mesh", "report")), st
    rerun(case)  # back to the defaults: the mesh re-runs again
    assert statuses(case)["mesh"] == "ran" and statuses(case)["nerf"] == "cached"


def test_from_reruns_downstream(first_run: tuple[Path, float]) -> None:
    case, _ = first_run
    rerun(case, "--from", "depth")
    st = statuses(case)
    assert [st[k] for k in ("ingest", "poses", "centerline", "nerf")] == ["cached"] * 4
    assert [st[k] for k in ("depth", "mesh", "report")] == ["ran"] * 3


def test_deleted_file_makes_stage_stale(first_run: tuple[Path, float]) -> None:
    case, _ = first_run
    (case / "01_ingest" / "masks" / "000003.png").unlink()
    rerun(case, "--until", "ingest")
    assert statuses(case)["ingest"] == "ran"
    assert (case / "01_ingest" / "masks" / "000003.png").is_file()


def test_depth_maps_stand_when_the_ground_truth_is_gone(first_run: tuple[Path, float]) -> None:
    """A case moved to another machine, or a data set no longer mounted: the depth stage still
    writes its maps, without scores, instead of failing after rendering them all."""
    case, _ = first_run
    gt = Path(last_record(case)["input"]).parent / "gt"
    hidden = gt.with_name("gt_hidden")
    gt.rename(hidden)
    try:
        rerun(case, "--from", "depth", "--until", "depth")
    finally:
        hidden.rename(gt)
    assert statuses(case)["depth"] == "ran"
    summary = json.loads((case / "05_depth" / "manifest.json").read_text())["summary"]
    assert summary["frames"] == len(list((case / "05_depth" / "depth").glob("*.npy")))
    assert summary["median_scaled"] is None and summary["gt_kind"] is None
