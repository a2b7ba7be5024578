"""The wheel: one import name (`endopipe`, with the engine, the stages and the libraries inside
it), every preset and data file shipped, and the installed copy runs away from the repository."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
#: repository folder -> where setup.py installs it
PACKAGE_ROOTS = {
    "endopipe": "endopipe",
    **{
        folder: f"endopipe/{folder}"
        for folder in ("pipeline", "stages", "jobs", "recording", "synth", "export")
    },
}
NOT_SOURCE = shutil.ignore_patterns(
    ".git", ".venv", "workdir", "build", "dist", "*.egg-info", "__pycache__", "*.pyc", ".*cache"
)


def run(args: list[str], cwd: Path, env: dict[str, str] | None = None) -> str:
    proc = subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True, timeout=180)
    assert proc.returncode == 0, (args, proc.stdout[-2000:], proc.stderr[-3000:])
    return proc.stdout


def data_files() -> set[str]:
    """Every non-Python file inside the package folders, as its path in the wheel."""
    out = set()
    for folder, installed in PACKAGE_ROOTS.items():
        for f in (REPO / folder).rglob("*"):
            rel = f.relative_to(REPO / folder)
            if f.is_file() and f.suffix not in {".py", ".pyc"} and "__pycache__" not in rel.parts:
                if not any(part.startswith(".") for part in rel.parts):  # editor temporaries
                    out.add(f"{installed}/{rel.as_posix()}")
    return out


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Built from a copy of the source (a stale build/ in the checkout cannot leak into it)."""
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"
    shutil.copytree(REPO, src, ignore=NOT_SOURCE)
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "-q"]
    run([*pip, "wheel", str(src), "--no-deps", "--no-build-isolation", "-w", str(tmp)], cwd=tmp)
    (built,) = tmp.glob("endopipe-*.whl")
    return built


@pytest.fixture(scope="module")
def installed(wheel: Path) -> Path:
    target = wheel.parent / "site"
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "-q"]
    run([*pip, "install", "--no-deps", "--target", str(target), str(wheel)], cwd=wheel.parent)
    return target


def test_the_wheel_owns_one_import_name_and_ships_every_data_file(wheel: Path) -> None:
    names = set(zipfile.ZipFile(wheel).namelist())
    tops = {n.split("/")[0] for n in names}
    packages = {t for t in tops if not t.endswith(".dist-info")}
    assert packages == {"endopipe"} and len(tops) == 2, tops  # no top-level pipeline, stages...
    assert {f"{installed}/__init__.py" for installed in PACKAGE_ROOTS.values()} <= names
    presets = {f"endopipe/configs/{f.name}" for f in (REPO / "endopipe" / "configs").glob("*.yaml")}
    assert {"endopipe/configs/default.yaml", "endopipe/configs/cavity.yaml"} <= presets
    missing = (presets | data_files()) - names
    assert not missing, f"not in the wheel (setup.py package_data): {sorted(missing)}"
    entry = next(n for n in names if n.endswith(".dist-info/entry_points.txt"))
    assert "endopipe = endopipe.cli:entry" in zipfile.ZipFile(wheel).read(entry).decode()


def test_the_installed_copy_runs_away_from_the_repository(installed: Path) -> None:
    env = {**os.environ, "PYTHONPATH": str(installed)}
    cwd = Path("/tmp")
    where = run(
        [sys.executable, "-c", "import endopipe.pipeline.runner as r, endopipe.stages as s; "
         "print(r.__file__); print(s.__file__)"],
        cwd, env,
    )  # fmt: skip
    assert all(line.startswith(str(installed)) for line in where.split()), where
    assert "batch" in run([sys.executable, "-m", "endopipe", "--help"], cwd, env)
    printed = run([sys.executable, "-m", "endopipe", "stages", "--yaml"], cwd, env)
    shipped = (installed / "endopipe" / "configs" / "default.yaml").read_text()
    assert printed.strip() == shipped.strip()
    resolved = run(
        [sys.executable, "-c", "from endopipe.cli import build_pipeline; "
         "from endopipe.pipeline.config import load_config, resolve_config_path; "
         "cfg = load_config(build_pipeline().stages, ['cavity']); "
         "print(resolve_config_path('cavity')); print(cfg['centerline'].prior)"],
        cwd, env,
    )  # fmt: skip
    path, prior = resolved.split()
    assert path == str(installed / "endopipe" / "configs" / "cavity.yaml")
    assert prior == "cavity"
