"""A stage killed (SIGKILL) or stopped (Ctrl-C, SIGTERM) leaves no partial stage folder; the next
run completes."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.conftest import textured_frames, write_video


def test_sigkill_mid_ingest_leaves_no_partial_folder(tmp_path: Path) -> None:
    video = write_video(tmp_path / "long.mp4", textured_frames(240, 320, 256))
    wd = tmp_path / "wd"
    cmd = [sys.executable, "-m", "endopipe", "run", str(video), "--workdir", str(wd)]
    cmd += ["--until", "ingest", "--quiet", "--set", "ingest.drop_duplicates=false"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    case = wd / "long"
    deadline = time.time() + 120
    while time.time() < deadline:  # wait until ingest is writing frames into its temp folder
        temps = list(case.glob(".01_ingest.tmp-*/frames/*.png"))
        if len(temps) >= 5:
            break
        assert proc.poll() is None, (
            "ingest finished before it could be killed; make the input longer"
        )
        time.sleep(0.02)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert not (case / "01_ingest").exists()
    assert list(case.glob(".01_ingest.tmp-*")), "the kill should have left only a temp folder"
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert (case / "01_ingest" / "manifest.json").is_file()
    assert len(list((case / "01_ingest" / "frames").glob("*.png"))) == 240
    assert not list(case.glob(".01_ingest.tmp-*")), "stale temp folders are cleaned"


def _wait_for_ingest_frames(proc: subprocess.Popen, case: Path, n: int = 5) -> None:
    """Until ingest is writing frames into its temporary folder (mid-stage)."""
    deadline = time.time() + 120
    while time.time() < deadline:
        if len(list(case.glob(".01_ingest.tmp-*/frames/*.png"))) >= n:
            return
        assert proc.poll() is None, "ingest finished before the signal; make the input longer"
        time.sleep(0.02)
    raise AssertionError("ingest never started writing frames")


@pytest.mark.parametrize(
    ("sig", "code", "said"),
    [(signal.SIGINT, 130, "interrupted"), (signal.SIGTERM, 143, "terminated (SIGTERM)")],
)
def test_a_stop_mid_stage_is_one_line_and_the_rerun_resumes(
    tmp_path: Path, sig: signal.Signals, code: int, said: str
) -> None:
    """Ctrl-C (SIGINT), or SIGTERM (a Slurm time limit or preemption, `kill`), is not success:
    one line naming the command that resumes, nothing half written. For SIGTERM, pycolmap's
    failure handler would otherwise print a native stack trace and kill the process."""
    video = write_video(tmp_path / "long.mp4", textured_frames(240, 320, 256))
    wd = tmp_path / "wd"
    args = ["run", str(video), "--workdir", str(wd), "--until", "ingest", "--quiet"]
    args += ["--set", "ingest.drop_duplicates=false"]
    cmd = [sys.executable, "-m", "endopipe", *args]
    # a shell's background job (`pytest &`) ignores SIGINT and its children inherit that, so
    # Python would install no Ctrl-C handler: give the run the default disposition a terminal has
    proc = subprocess.Popen(
        cmd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    _wait_for_ingest_frames(proc, wd / "long")
    os.kill(proc.pid, sig)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == code, stderr[-2000:]
    lines = [ln for ln in (stdout + stderr).splitlines() if ln.strip()]
    assert len(lines) == 1, lines
    assert said in lines[0] and "Traceback" not in stderr and "stack trace" not in stderr
    assert f"run the same command again: endopipe {' '.join(args)}" in lines[0]
    assert not (wd / "long" / "01_ingest").exists()
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert len(list((wd / "long" / "01_ingest" / "frames").glob("*.png"))) == 240


def test_a_local_worker_ends_with_the_process_that_started_it(tmp_path: Path) -> None:
    """SIGKILL to a batch-like parent only (not its group): its worker process must not run on
    as an orphan."""
    script = tmp_path / "parent.py"
    marker = tmp_path / "worker.pid"
    script.write_text(
        "import os, sys, time\n"
        "from endopipe.pipeline.executors import local_executor\n"
        "def work(path):\n"
        "    open(path, 'w').write(str(os.getpid()))\n"
        "    time.sleep(120)\n"
        "if __name__ == '__main__':\n"
        "    ex = local_executor(1, 1)\n"
        f"    ex.submit(work, {str(marker)!r})\n"
        "    time.sleep(120)\n"
    )
    proc = subprocess.Popen([sys.executable, str(script)], cwd=tmp_path)
    deadline = time.time() + 60
    while not marker.is_file() or not marker.read_text():
        assert time.time() < deadline, "the worker never started"
        time.sleep(0.05)
    worker = int(marker.read_text())
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    deadline = time.time() + 10
    while time.time() < deadline:
        try:
            os.kill(worker, 0)
        except ProcessLookupError:
            return
        time.sleep(0.1)
    os.kill(worker, signal.SIGKILL)
    raise AssertionError("the worker outlived its parent by 10 s")


def _pid(_: int) -> int:
    return os.getpid()


def test_each_case_gets_a_fresh_local_worker() -> None:
    """A worker's memory goes with it: the next case starts in a new process."""
    from endopipe.pipeline.executors import local_executor

    with local_executor(1, 1) as ex:
        pids = list(ex.map(_pid, range(3)))
    assert len(set(pids)) == 3
