"""The engine on toy stages: cache keys, staleness, --from / --until, atomic publish, locks."""

from __future__ import annotations

from pathlib import Path

import pytest
from filelock import FileLock
from pydantic import Field
from rich.console import Console

from endopipe.pipeline.cache import digest_text
from endopipe.pipeline.config import load_config
from endopipe.pipeline.errors import CaseLocked, ConfigError
from endopipe.pipeline.runner import Pipeline
from endopipe.pipeline.stage import CaseInfo, Stage, StageConfig, StageContext, Summary, write_json

CALLS: list[str] = []


class AConfig(StageConfig):
    value: int = Field(1, description="A number written to a.txt.")
    mode: str = Field("x", description="A label.")


class ASummary(Summary):
    value: int


class AView:
    """a's folder: the number it wrote."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder

    @property
    def value(self) -> int:
        return int((self.folder / "a.txt").read_text())


class A(Stage):
    """Writes a number."""

    name = "a"
    Config = AConfig
    Summary = ASummary
    View = AView

    def run(self, ctx: StageContext[AConfig]) -> ASummary:
        CALLS.append("a")
        (ctx.out / "a.txt").write_text(str(ctx.config.value))
        return ASummary(value=ctx.config.value)


class BConfig(StageConfig):
    fail: bool = Field(False, description="Raise halfway through, after writing a file.")


class BView:
    """b's folder: the doubled number."""

    def __init__(self, folder: Path) -> None:
        self.value = int((folder / "b.txt").read_text())


class B(Stage):
    """Doubles a's number."""

    name = "b"
    needs = ("a",)
    Config = BConfig
    View = BView

    def run(self, ctx: StageContext[BConfig]) -> Summary:
        CALLS.append("b")
        v = ctx.input(AView).value
        (ctx.out / "b.txt").write_text(str(2 * v))
        if ctx.config.fail:
            raise RuntimeError("boom")
        return Summary()


class C(Stage):
    """Adds one."""

    name = "c"
    needs = ("b",)

    def run(self, ctx: StageContext[StageConfig]) -> Summary:
        CALLS.append("c")
        v = ctx.input(BView).value
        (ctx.out / "c.txt").write_text(str(v + 1))
        return Summary()


@pytest.fixture()
def case(tmp_path: Path) -> Path:
    CALLS.clear()
    case_dir = tmp_path / "case"
    case_dir.mkdir()
    info = CaseInfo(name="case", input="x", kind="video", input_digest=digest_text("x"))
    write_json(case_dir / "case.json", info.model_dump())
    return case_dir


PIPE = Pipeline([A, B, C])


def configs(*sets: str):
    return load_config(PIPE.stages, [], list(sets), use_default_file=False)


def run(case: Path, *sets: str, **kw):
    CALLS.clear()
    return PIPE.run(case, configs(*sets), quiet=True, **kw)


def test_second_run_is_cached_and_outputs_are_right(case: Path) -> None:
    run(case)
    assert CALLS == ["a", "b", "c"]
    assert (case / "03_c" / "c.txt").read_text() == "3"
    record = run(case)
    assert CALLS == []
    assert [s.status for s in record.stages] == ["cached"] * 3
    assert len(list((case / "runs").glob("*.json"))) == 2


def test_config_change_reruns_stage_and_downstream_only(case: Path) -> None:
    run(case)
    run(case, "b.fail=false")  # same value as the default: same key
    assert CALLS == []
    run(case, "a.value=5")
    assert CALLS == ["a", "b", "c"]
    assert (case / "03_c" / "c.txt").read_text() == "11"
    run(case, "a.value=5")
    assert CALLS == []


def test_from_and_until(case: Path) -> None:
    run(case)
    run(case, from_stage="b")
    assert CALLS == ["b", "c"]
    run(case, until="b", force=True)
    assert CALLS == ["a", "b"]


def test_deleted_file_makes_stage_stale(case: Path) -> None:
    run(case)
    (case / "02_b" / "b.txt").unlink()
    plan = {p.stage: p for p in PIPE.status(case, configs())}
    assert plan["a"].fresh and not plan["b"].fresh and "b.txt" in plan["b"].reason
    run(case)
    assert CALLS == ["b", "c"]


def test_failure_leaves_previous_result_and_no_partial_folder(case: Path) -> None:
    run(case)
    before = (case / "02_b" / "b.txt").read_text()
    with pytest.raises(RuntimeError):
        run(case, "a.value=7", "b.fail=true")
    assert (case / "02_b" / "b.txt").read_text() == before  # the old good result stays
    assert not list(case.glob(".02_b.tmp-*"))
    record = sorted((case / "runs").glob("*.json"))[-1].read_text()
    assert '"failed"' in record and "boom" in record


def test_dry_run_changes_nothing(case: Path) -> None:
    record = run(case, dry_run=True)
    assert CALLS == [] and not (case / "01_a").exists()
    assert [s.status for s in record.stages] == ["ran"] * 3


def test_second_concurrent_run_gets_a_clear_message(case: Path) -> None:
    with FileLock(str(case / ".lock")):
        with pytest.raises(CaseLocked, match="another endopipe run"):
            PIPE.run(case, configs(), quiet=True)


@pytest.mark.parametrize(
    ("sets", "message"),
    [
        (["a.nope=1"], "unknown key 'a.nope' (--set); valid keys: value, mode"),
        (["zz.value=1"], "unknown stage 'zz' (--set); stages: a, b, c"),
        (["a.value=abc"], "a.value: Input should be a valid integer"),
        (["a=1"], "must name a stage and a key"),
    ],
)
def test_bad_settings_name_the_key(sets: list[str], message: str) -> None:
    with pytest.raises(ConfigError, match=message.replace("(", r"\(").replace(")", r"\)")):
        configs(*sets)


def test_config_files_layer_in_order(tmp_path: Path) -> None:
    f1, f2 = tmp_path / "one.yaml", tmp_path / "two.yaml"
    f1.write_text("a:\n  value: 3\n  mode: y\n")
    f2.write_text("a:\n  value: 4\n")
    cfg = load_config(PIPE.stages, [str(f1), str(f2)], ["a.mode=z"], use_default_file=False)
    assert cfg["a"].value == 4 and cfg["a"].mode == "z"


def test_status_names_the_changed_key_and_the_upstream(case: Path) -> None:
    run(case)
    plan = {p.stage: p for p in PIPE.status(case, configs("a.value=5", "a.mode=y"))}
    assert plan["a"].reason == 'a.mode "x" -> "y", a.value 1 -> 5'
    assert plan["b"].reason == "upstream a changed"
    assert plan["c"].reason == "upstream a changed"  # where the change began, not b


def test_status_judges_against_the_last_run_config(case: Path) -> None:
    run(case, "a.value=5")
    assert all(p.fresh for p in PIPE.status(case))  # not the defaults (a.value=1)
    run(case, "a.value=6", until="a")  # the last run's config moved on; b, c did not re-run
    plan = {p.stage: p for p in PIPE.status(case)}
    assert plan["a"].fresh and plan["b"].reason == "upstream a changed"
    again = load_config(PIPE.stages, [str(case / "config.yaml")], use_default_file=False)
    assert again["a"].value == 6  # the recorded config is a --config file that repeats the run


def test_status_of_a_case_run_before_configs_were_recorded(case: Path) -> None:
    run(case, "a.value=5")
    (case / "config.yaml").unlink()  # as an older endopipe left it: each manifest's config
    assert all(p.fresh for p in PIPE.status(case))


class AsksForB(Stage):
    """Needs a, asks for b's view."""

    name = "d"
    needs = ("a",)

    def run(self, ctx: StageContext[StageConfig]) -> Summary:
        CALLS.append("d")
        ctx.input(BView)
        return Summary()


class WrongSummary(Stage):
    """Returns a's summary instead of its own."""

    name = "d"
    needs = ("a",)
    Summary = ASummary

    def run(self, ctx: StageContext[StageConfig]) -> Summary:
        (ctx.out / "d.txt").write_text("written")
        return Summary()


def test_input_refuses_a_view_no_needed_stage_has(case: Path) -> None:
    pipe = Pipeline([A, B, AsksForB])
    configs = load_config(pipe.stages, use_default_file=False)
    with pytest.raises(
        LookupError, match=r"asked for BView, but no stage it needs has it; its needs: a \(AView\)"
    ):
        pipe.run(case, configs, quiet=True)
    assert not (case / "03_d").exists() and not list(case.glob(".03_d.tmp-*"))


def test_input_opens_the_needed_stage_by_its_view_class(tmp_path: Path) -> None:
    (tmp_path / "a.txt").write_text("7")
    ctx = StageContext(
        case_dir=tmp_path,
        out=tmp_path / "out",
        config=BConfig(),
        case=CaseInfo(name="c", input="x", kind="video", input_digest="0"),
        inputs={"a": tmp_path},
        views={"a": AView},
        console=Console(quiet=True),
    )
    view = ctx.input(AView)
    assert isinstance(view, AView) and view.value == 7
    assert ctx.input(AView) is view  # opened once
    assert ctx.input_by_name("a") is view and ctx.input_dir("a") == tmp_path
    with pytest.raises(LookupError, match="'b' is not among this stage's needs"):
        ctx.input_by_name("b")


def test_a_run_returning_another_summary_fails_and_publishes_nothing(case: Path) -> None:
    pipe = Pipeline([A, WrongSummary])
    configs = load_config(pipe.stages, use_default_file=False)
    with pytest.raises(TypeError, match="stage d: run returned Summary, not its Summary ASummary"):
        pipe.run(case, configs, quiet=True)
    assert (case / "01_a").is_dir()
    assert not (case / "02_d").exists() and not list(case.glob(".02_d.tmp-*"))


def test_a_config_of_another_stage_is_refused_before_the_run(case: Path) -> None:
    cfgs = configs()
    cfgs["b"] = AConfig()
    with pytest.raises(
        TypeError, match="stage b was given a AConfig; it takes its Config, BConfig"
    ):
        PIPE.run(case, cfgs, quiet=True)
    assert CALLS == ["a"]  # b never started
