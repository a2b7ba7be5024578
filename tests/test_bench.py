"""`endopipe bench`: plan selection, and a failing run is a row (with its reason and only the
stages that run produced), not the end of the bench."""

from __future__ import annotations

from pathlib import Path

import pytest
from rich.console import Console

from endopipe.cli import build_pipeline, prepare_case
from endopipe.commands.bench import run_bench
from endopipe.commands.bench_plan import BenchCase, BenchPlan, plan
from endopipe.commands.bench_tables import markdown_table
from endopipe.pipeline.errors import ConfigError, SummaryMismatch


def test_case_filter_and_unknown_case() -> None:
    assert [c.name for c in plan(False, ["cavity"]).cases] == ["cavity"]
    assert len(plan(False).cases) == 2 and plan(False).variants[0] == "full"
    lens = plan(False, ["colon_barrel", "colon_barrel_est"]).cases
    assert [c.lens for c in lens] == ["barrel", "barrel"]
    assert [c.given_lens for c in lens] == [True, False]
    with pytest.raises(ConfigError, match="unknown bench case nope"):
        plan(False, ["nope"])


def test_variant_filter_keeps_the_table_order_and_rejects_unknown_names() -> None:
    assert plan(False, None, ["plain", "full"]).variants == ["full", "plain"]
    assert plan(True, None, ["no_prior"]).variants == ["no_prior"]
    with pytest.raises(ConfigError, match="unknown bench variant no_geo"):
        plan(True, None, ["no_geo"])  # the quick bench has no no_geo run


def test_a_failing_run_becomes_a_row_and_the_bench_goes_on(tmp_path: Path) -> None:
    # One frame is not a sequence: ingest's quality gate fails in seconds.
    tiny = BenchPlan(
        cases=[BenchCase(name="tiny", shape="colon", frames=4, width=64, height=48, seed=1)],
        variants=["full", "no_prior"],
        sets=["ingest.max_frames=1"],
    )
    saved: list[int] = []
    rows = run_bench(
        build_pipeline(),
        tmp_path,
        tiny,
        prepare_case,
        Console(quiet=True),
        on_row=lambda rows: saved.append(len(rows)),
    )
    assert [r["variant"] for r in rows] == ["full", "no_prior"] and saved == [1, 2]
    for row in rows:
        assert row["error"] and "usable frame" in row["error"]
        assert row["abs_rel"] is None and row["chamfer"] is None  # nothing stale reported
    table = markdown_table(rows)
    assert "full (failed)" in table and "- tiny / no_prior failed: " in table


def test_rows_and_table_put_the_two_guesses_beside_ours(tmp_path: Path) -> None:
    import numpy as np

    from endopipe.commands.bench import collect_row
    from endopipe.commands.bench_tables import COLUMNS, write_csv
    from endopipe.pipeline.cache import Manifest
    from endopipe.stages.depth.stage import DepthSummary
    from endopipe.stages.metrics.depth import depth_sequence_metrics

    gt = np.linspace(10, 40, 48, dtype=np.float32).reshape(6, 8)
    ours = gt * np.where(np.arange(48).reshape(6, 8) % 2, 1.4, 0.7).astype(np.float32)
    ours[0] = 0.0  # one row of holes: coverage 5/6
    scored = {
        "ours": depth_sequence_metrics([ours], [gt]),
        "radial": depth_sequence_metrics([np.where(ours > 0, gt * 3, 0)], [gt]),  # exact
        "brightness": depth_sequence_metrics([np.where(ours > 0, 1 / gt, 0)], [gt]),
    }
    guesses = {
        name: {k: v for k, v in m.items() if k != "per_frame"}
        for name, m in scored.items()
        if name != "ours"
    }
    summary = DepthSummary(
        frames=1,
        units="mm",
        png_scale=1.0,
        ms_per_frame=1.0,
        bake_s=0.0,
        renderer="baked",
        median_scaled=scored["ours"]["median_scaled"],
        coverage=5 / 6,
        baselines=guesses,
    )
    pipe = build_pipeline()
    folder = pipe.folder(tmp_path, "depth")
    folder.mkdir(parents=True)
    manifest = Manifest(
        stage="depth",
        key="k",
        version=2,
        config={},
        upstream={},
        started=0.0,
        finished=1.0,
        wall_s=1.0,
        peak_rss_mb=1.0,
        summary=summary.model_dump(),
        files={},
    )
    (folder / "manifest.json").write_text(manifest.model_dump_json())
    row = collect_row(pipe, tmp_path, "wall", "full", 1.0, {"depth"})
    assert abs(row["coverage"] - 5 / 6) < 1e-9
    assert row["radial_abs_rel"] < 1e-6 < row["abs_rel"] < row["brightness_abs_rel"]
    assert row["radial_delta1"] == 1.0
    table = markdown_table([row])
    assert "| AbsRel ours | AbsRel radial | AbsRel brightness |" in table
    assert table.splitlines()[-1].endswith("| **no** |")  # the radial guess is better here
    write_csv(tmp_path / "bench.csv", [row])
    header = (tmp_path / "bench.csv").read_text().splitlines()[0].split(",")
    assert header == list(COLUMNS) and "brightness_delta1" in header

    # A summary field renamed on one side fails the row loudly instead of blanking a column.
    renamed = summary.model_dump() | {"coverage_share": 5 / 6}
    del renamed["coverage"]
    manifest.summary = renamed
    (folder / "manifest.json").write_text(manifest.model_dump_json())
    with pytest.raises(SummaryMismatch, match="coverage_share"):
        collect_row(pipe, tmp_path, "wall", "full", 1.0, {"depth"})


def test_the_pose_sweep_plan_varies_what_sfm_finds_hard() -> None:
    from endopipe.commands.bench import input_name

    sweep = plan(False, sweep="poses")
    assert sweep.until == "poses" and sweep.variants == ["full"] and len(sweep.cases) >= 8
    cases = sweep.cases
    assert {c.shape for c in cases} == {"colon", "cavity"}
    assert {("colon", 7), ("cavity", 7)} <= {(c.shape, c.seed) for c in cases}
    assert len({c.seed for c in cases}) >= 3
    assert {c.texture_contrast for c in cases} >= {0.5, 0.75, 1.0}
    assert any(c.vignetting == 0.4 for c in cases) and any(c.lens == "barrel" for c in cases)
    assert all((c.frames, c.width, c.height) == (60, 320, 256) for c in cases)
    # cases that differ in what is rendered never share an input folder
    assert len({input_name(c) for c in cases}) == len(cases)
    assert input_name(cases[0]) == "colon_s7_60x320x256"  # the bench colon's own input
    twins = [
        cases[0].model_copy(update=u) for u in ({"vignetting": 0.4}, {"texture_contrast": 0.5})
    ]
    assert len({input_name(c) for c in [cases[0], *twins]}) == 3
    assert [c.name for c in plan(False, ["cavity_s7"], sweep="poses").cases] == ["cavity_s7"]
    with pytest.raises(ConfigError, match="unknown bench case colon;"):
        plan(False, ["colon"], sweep="poses")  # the table's case is not a sweep case
    with pytest.raises(ConfigError, match="unknown sweep nerf"):
        plan(False, sweep="nerf")
    with pytest.raises(ConfigError, match="no --variant"):
        plan(False, None, ["full"], sweep="poses")


def _sweep_row(case: str, ate: float | None, verdict: str | None, **kw) -> dict:
    row = dict.fromkeys(
        ("registered", "mapper", "doubtful_count", "disagreement_pct", "poses_s", "error")
    )
    row.update(case=case, shape="colon", seed=7, contrast=1.0, vignetting=0.0, lens="pinhole")
    row.update(ate_pct=ate, verdict=verdict, reasons="", other="", doubtful_frames="")
    return {**row, **kw}


def test_pose_table_tallies_the_verdict_against_the_ate(tmp_path: Path) -> None:
    from endopipe.commands.bench import count_ranges
    from endopipe.commands.bench_tables import POSE_COLUMNS, pose_table, write_pose_csv

    assert count_ranges("0-2, 7, 9-10") == 6 and count_ranges("") == 0
    rows = [
        _sweep_row("a", 0.4, "ok", registered=1.0, mapper="global", doubtful_count=0),
        _sweep_row("b", 2.0, "doubtful", reasons="scale drift: 5.0x along the path (> 4x)"),
        _sweep_row("c", 3.5, "ok"),  # between the yardsticks: counted in neither
        _sweep_row("d", 17.7, "doubtful", other="incremental: sound on its own"),
        _sweep_row("e", 6.0, "ok"),  # wrong and not caught
        _sweep_row("f", None, None, error="poses: only 3 of 60 frames registered"),
    ]
    table = pose_table(rows)
    assert (
        "ATE ≤ 2%: 2 of 6 cases; ATE > 5%: 2, of them marked doubtful: 1; "
        "ATE ≤ 2% marked doubtful: 1; no ATE (failed or no ground truth): 1"
    ) in table
    lines = table.splitlines()
    assert lines[2] == (
        "| a | colon | 7 | 1 | 0 | pinhole | 1.00 | 0.40 | global | ok | – | 0 | – | – | – |"
    )
    assert "| doubtful | scale drift: 5.0x along the path |" in lines[3]  # threshold dropped
    assert (
        "| failed |" in lines[7]
        and lines[-1] == "- f failed: poses: only 3 of 60 frames registered"
    )
    write_pose_csv(tmp_path / "poses.csv", rows)
    header = (tmp_path / "poses.csv").read_text().splitlines()[0].split(",")
    assert header == list(POSE_COLUMNS)


def test_the_sweep_option_writes_its_own_table(tmp_path: Path, monkeypatch) -> None:
    from typer.testing import CliRunner

    from endopipe import cli
    from endopipe.commands import bench

    seen = {}

    def fake_run(pipe, workdir, bench_plan, prepare, console, sets, on_row, collect):
        seen.update(until=bench_plan.until, collect=collect)
        rows = [_sweep_row("colon_s7", 0.3, "ok")]
        on_row(rows)
        return rows

    monkeypatch.setattr(bench, "run_bench", fake_run)
    args = ["bench", "--sweep", "poses", "--case", "colon_s7", "--workdir", str(tmp_path)]
    result = CliRunner().invoke(cli.app, args)
    assert result.exit_code == 0, result.output
    assert seen == {"until": "poses", "collect": bench.pose_row}
    assert "ATE ≤ 2%: 1 of 1 cases" in (tmp_path / "poses.md").read_text()
    assert (tmp_path / "poses.csv").is_file() and not (tmp_path / "bench.md").exists()


def test_a_sweep_run_stops_after_poses_and_its_row_reads_the_verdict(tmp_path: Path) -> None:
    from endopipe.commands.bench import pose_row
    from endopipe.commands.bench_tables import pose_table

    # Ground-truth poses (no COLMAP): the run is seconds, the row is exact.
    case = BenchCase(
        name="gt", shape="colon", frames=8, width=96, height=80, seed=2, vignetting=0.3
    )
    sweep = BenchPlan(cases=[case], variants=["full"], sets=["poses.source=gt"], until="poses")
    pipe = build_pipeline()
    rows = run_bench(pipe, tmp_path, sweep, prepare_case, Console(quiet=True), collect=pose_row)
    (row,) = rows
    assert row["error"] is None and row["registered"] == 1.0 and row["ate_pct"] < 1e-6
    assert row["verdict"] == "not assessed" and row["doubtful_count"] == 0
    assert (row["vignetting"], row["lens"]) == (0.3, "pinhole")
    assert (tmp_path / "inputs" / "colon_s2_8x96x80_v0.3" / "video.mp4").is_file()
    case_dir = tmp_path / "runs" / "gt"
    assert pipe.manifest(case_dir, "poses") and not pipe.folder(case_dir, "centerline").exists()
    assert "| not assessed |" in pose_table(rows)


def test_the_profile_shows_each_stages_time_cpu_and_memory_beside_the_accuracy(
    tiny_case: Path,
) -> None:
    from endopipe.commands.profile import profile_rows, profile_table

    rows = profile_rows(build_pipeline(), tiny_case, 1.0)
    stages = [r.stage for r in rows]
    assert stages == ["ingest", "poses", "centerline", "nerf", "depth", "mesh", "report", "all"]
    by = {r.stage: r for r in rows}
    for r in rows[:-1]:
        assert r.wall_s > 0 and r.cpu_s is not None and r.cpu_s > 0 and r.peak_mb > 50, r
    # the NeRF trains with one torch thread here: about one core busy, never several
    assert 0.5 < by["nerf"].threads_busy < 1.6, by["nerf"]
    assert "600 steps" in by["nerf"].note and "ms per map" in by["depth"].note
    assert "AbsRel" in by["all"].note and "Chamfer" in by["all"].note
    assert by["all"].cpu_s == pytest.approx(sum(r.cpu_s for r in rows[:-1]))
    assert "| colon | **all** |" in profile_table(rows)
