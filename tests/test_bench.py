"""`endopipe bench`: plan selection, and a failing run is a row (with its reason and only the
stages that run produced), not the end of the bench."""

from __future__ import annotations

from pathlib import Path

import pytest
from rich.console import Console

from endopipe.cli import build_pipeline, prepare_case
from endopipe.commands.bench import BenchCase, BenchPlan, markdown_table, plan, run_bench
from endopipe.pipeline.errors import ConfigError


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

    from endopipe.commands.bench import COLUMNS, collect_row, write_csv
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
