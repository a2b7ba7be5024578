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
