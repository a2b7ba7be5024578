"""`endopipe batch` over a mixed folder (a synthetic case, Hamlyn, C3VD and SimCol3D sequences and
a truncated video) with each executor: good cases complete, the broken one is reported with its
reason, batch.csv / batch.html are written, and a second run re-runs nothing."""

from __future__ import annotations

import csv
import os
import pickle
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from endopipe.cli import batch_case, main
from endopipe.jobs.driver import run_cases
from endopipe.jobs.rows import CaseRow, CaseTask
from endopipe.pipeline.errors import EndopipeError
from endopipe.pipeline.executors import (
    ClusterConfig,
    load_cluster_config,
    local_jobs,
    make_executor,
    thread_env,
    threads,
    threads_per_job,
)
from endopipe.pipeline.executors.threads import auto_threads
from tests.conftest import textured_frames, write_video
from tests.test_datasets import write_c3vd, write_hamlyn, write_simcol

GOOD = {
    "synth__colon": "case",
    "hamlyn__rectified01": "hamlyn",
    "c3vd__cecum_t1_a": "c3vd",
    "SimCol3D__SyntheticColon_I__Frames_S1": "simcol3d",
}
BROKEN = "videos__broken"


def make_batch_folder(root: Path) -> Path:
    """The mixed folder every executor test runs on (8 frames a case, 128x96 or less)."""
    from endopipe.synth import SynthConfig, generate_case

    generate_case(root / "synth" / "colon", SynthConfig(seed=3, frames=8, width=128, height=96))
    write_hamlyn(root / "hamlyn" / "rectified01", n=8, seed=1)
    write_c3vd(root / "c3vd" / "cecum_t1_a", n=8, seed=2)
    write_simcol(root / "SimCol3D" / "SyntheticColon_I", n=8, seed=4)
    (root / "videos").mkdir()
    good = write_video(root / "videos" / "good.mp4", textured_frames(12, 128, 96, seed=5))
    data = good.read_bytes()
    (root / "videos" / "broken.mp4").write_bytes(data[: len(data) * 2 // 3])
    good.unlink()
    return root


@pytest.fixture(scope="module")
def batch_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_batch_folder(tmp_path_factory.mktemp("batch") / "data")


def read_csv(workdir: Path) -> dict[str, dict[str, str]]:
    with open(workdir / "batch.csv", newline="") as f:
        return {row["case"]: row for row in csv.DictReader(f)}


def run_batch(folder: Path, workdir: Path, *extra: str) -> tuple[int, float]:
    t0 = time.perf_counter()
    code = main(["batch", str(folder), "--workdir", str(workdir), "--until", "ingest", *extra])
    return code, time.perf_counter() - t0


def check_first_run(workdir: Path, code: int) -> dict[str, dict[str, str]]:
    assert code == 3  # one case failed, the batch still finished
    rows = read_csv(workdir)
    assert set(rows) == {*GOOD, BROKEN}
    for name, reader in GOOD.items():
        row = rows[name]
        assert (row["status"], row["reader"], row["stages_ran"]) == ("ok", reader, "ingest"), row
        assert int(float(row["ingest.kept"])) >= 3 and float(row["wall_s"]) > 0
        assert float(row["peak_rss_mb"]) > 0 and float(row["compute_s"]) > 0
        assert (workdir / name / "01_ingest" / "frames.json").is_file()
    assert rows["hamlyn__rectified01"]["gt_kind"] == "pseudo"
    assert rows["c3vd__cecum_t1_a"]["gt_kind"] == "exact"
    assert rows["synth__colon"]["gt_kind"] == "exact"
    broken = rows[BROKEN]
    assert broken["status"] == "failed" and broken["reader"] == "video"
    assert broken["failed_stage"] == "ingest"  # the stage that reads the input
    assert "broken.mp4" in broken["reason"] and "\n" not in broken["reason"]
    assert "Traceback" not in broken["reason"] and "internal error" not in broken["reason"]
    page = (workdir / "batch.html").read_text()
    assert "<table>" in page and "mean" in page and "median" in page
    assert all(name in page for name in rows) and "pseudo" in page
    assert "http" not in page.replace("http-equiv", "")  # self-contained
    return rows


def check_second_run(workdir: Path, code: int, first: dict[str, dict[str, str]]) -> None:
    assert code == 3  # the broken case is tried again and fails again
    rows = read_csv(workdir)
    for name in GOOD:
        assert rows[name]["status"] == "ok" and rows[name]["stages_ran"] == "", rows[name]
        assert rows[name]["stages_cached"] == "ingest"
        # wall_s stays the time of the run that made the outputs; this batch's own is apart
        assert rows[name]["wall_s"] == first[name]["wall_s"]
        assert 0 < float(rows[name]["this_batch_s"]) < 5
    assert rows[BROKEN]["status"] == "failed" and rows[BROKEN]["failed_stage"] == "ingest"


def test_local_batch_then_rerun_runs_nothing(batch_folder: Path, tmp_path: Path, capsys) -> None:
    wd = tmp_path / "wd"
    code, first = run_batch(batch_folder, wd, "--jobs", "2")
    out = capsys.readouterr()
    rows = check_first_run(wd, code)
    assert "hamlyn" in out.out and "simcol3d" in out.out and "c3vd" in out.out  # reader picked
    assert "error" in out.err.splitlines()[-1] and "1 of 5 case(s) failed" in out.err
    stamps = {n: (wd / n / "01_ingest" / "manifest.json").stat().st_mtime_ns for n in GOOD}
    code, second = run_batch(batch_folder, wd, "--jobs", "2")
    check_second_run(wd, code, rows)
    assert stamps == {n: (wd / n / "01_ingest" / "manifest.json").stat().st_mtime_ns for n in GOOD}
    assert second < first / 2, (first, second)  # nothing to do: no worker is even started
    print(f"local executor: first {first:.1f} s, second {second:.1f} s", file=sys.stderr)


def test_config_change_reruns_only_what_changed(batch_folder: Path, tmp_path: Path) -> None:
    wd = tmp_path / "wd"
    one = batch_folder / "hamlyn"
    assert run_batch(one, wd)[0] == 0
    assert run_batch(one, wd, "--set", "ingest.max_frames=5")[0] == 0
    row = read_csv(wd)["rectified01"]
    assert row["stages_ran"] == "ingest" and float(row["ingest.kept"]) == 5


@pytest.mark.slow  # 9 s; an optional executor (the local one is the default)
def test_slurm_executor_through_submitit_local(batch_folder: Path, tmp_path: Path) -> None:
    pytest.importorskip("submitit")
    wd = tmp_path / "wd"
    cfg = tmp_path / "cluster.yaml"
    cfg.write_text("slurm:\n  cluster: local\n  gpus_per_node: 0\n  timeout_min: 10\n")
    extra = ("--executor", "slurm", "--cluster-config", str(cfg), "--jobs", "2")
    code, first = run_batch(batch_folder, wd, *extra)
    rows = check_first_run(wd, code)
    assert list((wd / ".batch" / "slurm").glob("*/*_log.out"))  # submitit's logs, in the workdir
    code, second = run_batch(batch_folder, wd, *extra)
    check_second_run(wd, code, rows)
    print(f"slurm (submitit local): first {first:.1f} s, second {second:.1f} s", file=sys.stderr)


def test_slurm_job_array_script_from_the_cluster_config(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """What sbatch would get on a real cluster (no Slurm here): one array, the config's
    resources, thread limits, logs in the workdir."""
    pytest.importorskip("submitit")
    import shutil

    from endopipe.pipeline.executors import SlurmSettings, SubmititExecutor

    monkeypatch.setattr(shutil, "which", lambda name: f"/usr/bin/{name}")
    settings = SlurmSettings(partition="gpu", gpus_per_node=1, cpus_per_task=6, timeout_min=90)
    settings.setup = ["module load cuda/12.1"]
    ex = SubmititExecutor(settings, tmp_path / "wd", jobs=2)
    assert ex.cluster == "slurm" and ex.max_in_flight is None and ex.threads == 6
    slurm = ex._ex._executor
    slurm.parameters["map_count"] = 5  # what submitting 5 cases in one batch() sets
    script = slurm._make_submission_file_text("CMD", "uid")
    for line in (
        "#SBATCH --array=0-4%2",
        "#SBATCH --gpus-per-node=1",
        "#SBATCH --cpus-per-task=6",
        "#SBATCH --partition=gpu",
        "#SBATCH --time=90",
        "export OMP_NUM_THREADS=6",
        "module load cuda/12.1",
        f"{(tmp_path / 'wd').resolve()}/.batch/slurm/%A_%a/",
    ):
        assert line in script, line


@pytest.mark.slow  # 11 s; an optional executor (the local one is the default)
def test_ray_executor_on_a_local_ray_cluster(batch_folder: Path, tmp_path: Path) -> None:
    pytest.importorskip("ray")
    wd = tmp_path / "wd"
    code, first = run_batch(batch_folder, wd, "--executor", "ray", "--jobs", "2")
    rows = check_first_run(wd, code)
    code, second = run_batch(batch_folder, wd, "--executor", "ray", "--jobs", "2")
    check_second_run(wd, code, rows)
    print(f"ray (local cluster): first {first:.1f} s, second {second:.1f} s", file=sys.stderr)


# ---------------------------------------------------------------- the seam's contracts


def test_case_function_is_picklable_and_never_raises(tmp_path: Path) -> None:
    assert pickle.loads(pickle.dumps(batch_case)) is batch_case
    task = CaseTask(
        name="gone", input=str(tmp_path / "gone.mp4"), reader="auto",
        workdir=str(tmp_path / "wd"), configs={}, until="ingest",
    )  # fmt: skip
    row = batch_case(pickle.loads(pickle.dumps(task)))
    assert isinstance(row, CaseRow) and row.status == "failed"
    assert row.reason.startswith("input not found")
    bad = task.model_copy(update={"configs": {"ingest": {"stride": "two"}}})
    assert batch_case(bad).reason.startswith("internal error")  # caught, not raised


def crash_or_ok(task: CaseTask) -> CaseRow:
    """A case function whose 'crash' case kills its worker process outright."""
    if task.check_only:  # the driver's in-process check: every case has work to do
        return CaseRow(case=task.name, status="pending", reader=task.reader)
    if task.name == "crash":
        os._exit(7)
    return CaseRow(case=task.name, status="ok", reader=task.reader, metrics={"x": 1.0})


def test_a_crashing_case_does_not_take_the_batch_down(tmp_path: Path) -> None:
    tasks = [
        CaseTask(name=n, input=n, reader="video", workdir=str(tmp_path), configs={})
        for n in ("a", "crash", "b")
    ]
    rows = run_cases("local", crash_or_ok, tasks, jobs=2, workdir=tmp_path, cluster=ClusterConfig())
    assert [r.status for r in rows] == ["ok", "failed", "ok"]
    assert "worker process died" in rows[1].reason


def test_missing_extras_are_one_line(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setitem(sys.modules, "ray", None)
    monkeypatch.setitem(sys.modules, "submitit", None)
    for kind, hint in (("ray", "endopipe[ray]"), ("slurm", "endopipe[slurm]")):
        with pytest.raises(EndopipeError, match=hint.replace("[", r"\[").replace("]", r"\]")):
            make_executor(kind, jobs=1, workdir=tmp_path, cluster=ClusterConfig())


def test_cluster_config_is_valid_and_checked(tmp_path: Path) -> None:
    cfg = load_cluster_config()  # configs/cluster.yaml as shipped
    assert cfg.slurm.gpus_per_node >= 1 and cfg.ray.num_gpus >= 1
    bad = tmp_path / "c.yaml"
    bad.write_text("slurm:\n  gpus_per_nod: 1\n")
    with pytest.raises(EndopipeError, match="gpus_per_nod"):
        load_cluster_config(bad)


def test_threads_are_shared_between_jobs(monkeypatch) -> None:
    cores = len(os.sched_getaffinity(0))
    assert threads_per_job(1) == cores
    assert threads_per_job(cores * 4) == 1
    assert threads_per_job(2) == max(1, cores // 2)
    # Without --jobs: one job a core, never more jobs than tasks, one beside a GPU.
    assert local_jobs(1) == 1
    assert 1 <= local_jobs(cores * 4) <= cores
    monkeypatch.setattr(threads, "_has_gpu", lambda: True)
    assert local_jobs(cores * 4) == 1
    # A stage picking its own threads stays under its job's share, even on an idle machine.
    with thread_env(1):
        assert auto_threads(window_s=0.05) == 1


def test_no_cases_and_bad_executor_are_one_line(tmp_path: Path, capsys) -> None:
    (tmp_path / "empty").mkdir()
    assert main(["batch", str(tmp_path / "empty"), "--workdir", str(tmp_path / "wd")]) == 2
    assert "no cases found" in capsys.readouterr().err
    args = ["batch", str(tmp_path), "--workdir", str(tmp_path / "wd"), "--executor", "k8s"]
    assert main(args) == 2
    assert "'k8s' is not one of local, slurm, ray" in capsys.readouterr().err


def test_batch_page_links_each_case_to_its_report(tmp_path: Path) -> None:
    from endopipe.commands.batch.page import write_html
    from endopipe.commands.batch.table import write_csv

    rows = [
        CaseRow(case="a", status="ok", reader="case", report="a/07_report/report.html",
                metrics={"depth.abs_rel": 0.1}),
        CaseRow(case="b", status="ok", reader="case", metrics={"depth.abs_rel": 0.3}),
    ]  # fmt: skip
    page = write_html(rows, tmp_path / "batch.html").read_text()
    assert "<a href='a/07_report/report.html'>a</a>" in page and "<a href='b" not in page
    assert "<td>0.2</td>" in page  # the mean row of abs_rel
    write_csv(rows, tmp_path / "batch.csv")
    assert read_csv(tmp_path)["a"]["report"] == "a/07_report/report.html"


def test_rows_name_the_failed_stage_and_keep_the_wall_time_of_the_outputs(tmp_path: Path) -> None:
    """batch.csv's columns from one case function: a failure names its stage (also when the
    input cannot even be opened), and a cached re-run keeps the time the outputs took."""
    videos = tmp_path / "videos"
    videos.mkdir()
    good = write_video(videos / "good.mp4", textured_frames(8, 64, 48))
    write_video(videos / "black.mp4", [np.zeros((48, 64, 3), np.uint8)] * 8)
    (videos / "broken.mp4").write_bytes(good.read_bytes()[:200])

    def task(name: str, **update) -> CaseTask:
        return CaseTask(
            name=name, input=str(videos / f"{name}.mp4"), reader="video",
            workdir=str(tmp_path / "wd"), configs={}, until="ingest", **update,
        )  # fmt: skip

    for name, reason in (("broken", "cannot read"), ("black", "are blank")):
        row = batch_case(task(name))
        assert (row.status, row.failed_stage) == ("failed", "ingest"), row
        assert reason in row.reason and row.wall_s == row.this_batch_s > 0
    first = batch_case(task("good"))
    assert first.status == "ok" and first.failed_stage is None and first.wall_s > 0
    again = batch_case(task("good", check_only=True))  # what a re-run does with a done case
    assert again.status == "ok" and again.stages_cached == ["ingest"]
    assert again.wall_s == first.wall_s and again.this_batch_s < first.this_batch_s


def test_a_doubtful_pose_verdict_reaches_batch_csv_and_page(tmp_path: Path) -> None:
    """The poses' verdict (02_poses/verdict.json) in its own columns, just before the poses
    stage's numbers; a case from before the verdict leaves them empty."""
    from endopipe.commands.batch.page import write_html
    from endopipe.commands.batch.table import write_csv
    from endopipe.jobs.case import note_pose_verdict
    from endopipe.stages.poses.verdict import FrameVerdict, PoseVerdict
    from tests.handmade_case import make_case

    reasons = ["scale drift: the scene's depth changes 7.3x along the path (> 4x)", "only 5 of 6"]
    frames = [FrameVerdict(index=i, status="ok") for i in range(6)]
    for i in (1, 2, 5):
        frames[i] = FrameVerdict(index=i, status="doubtful", reasons=["jumps"])
    frames[4] = FrameVerdict(index=4, status="unregistered")  # not counted as doubtful
    verdict = PoseVerdict(status="doubtful", reasons=reasons, mapper="global", frames=frames)
    rows = []
    for name, written in (("new", verdict), ("old", None)):
        case = make_case(tmp_path / name, gt=False, stages=("ingest", "poses"))
        if written is not None:
            written.write(case / "02_poses" / "verdict.json")
        row = CaseRow(case=name, status="ok", reader="case")
        row.metrics = {"ingest.kept": 6.0, "poses.registered": 5.0, "poses.depth_drift": 7.3}
        note_pose_verdict(row, case / "02_poses")
        rows.append(row)

    write_csv(rows, tmp_path / "batch.csv")
    with open(tmp_path / "batch.csv", newline="") as f:
        header = next(csv.reader(f))
    pose_cols = ["pose_verdict", "pose_reasons", "mapper", "doubtful_frames"]
    at = header.index("poses.registered")
    assert header[at - 4 : at] == pose_cols and header[at - 5] == "ingest.kept"
    table = read_csv(tmp_path)
    new, old = table["new"], table["old"]
    assert [new[c] for c in pose_cols] == ["doubtful", "; ".join(reasons), "global", "3"]
    assert [old[c] for c in pose_cols] == ["", "", "", ""]

    page = write_html(rows, tmp_path / "batch.html").read_text()
    assert "<span class='doubtful'>doubtful</span>" in page
    assert "1 with doubtful poses" in page
    assert "scale drift: the scene&#x27;s depth changes 7.3x" in page
