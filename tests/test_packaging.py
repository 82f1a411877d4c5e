"""A plain `pip install .` carries everything the commands need, the bundled demos included.

The bundled .mcap files live in the top-level datasets/ folder (data only) and ship as the
data-only package `imitation.datasets` (pyproject.toml, setup.py); imitation/bundled.py finds them
in a source checkout and in an installed package. Builds run on a copy of the project, so that
setuptools' build/ and egg-info never land in the shared checkout (a stale build/lib would also
leak deleted modules into the wheel). Nothing here reaches the network: pip is told to use no
index and no version check, Hugging Face is offline with a private cache.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest
from support import DATASETS, REPO

from imitation.bundled import bundled_datasets

# What a build never reads: the virtualenvs, run outputs and caches of a working checkout.
_NOT_SOURCE = {".git", "build", "dist", "runs", "mutants", "demo-output", ".pytest_cache", ".hypothesis", "bench/data"}


def _offline_env(tmp_path: Path) -> dict[str, str]:
    env = {key: value for key, value in os.environ.items() if key not in ("PYTHONPATH", "PYTHONHOME")}
    env.update(HF_HUB_OFFLINE="1", HF_HOME=str(tmp_path / "hf"), PIP_NO_INDEX="1", PIP_DISABLE_PIP_VERSION_CHECK="1", PIP_NO_INPUT="1")
    return env


def _copy_project(tmp_path: Path) -> Path:
    def ignore(folder: str, names: list[str]) -> set[str]:
        where = Path(folder).relative_to(REPO)
        return {name for name in names
                if (where / name).as_posix() in _NOT_SOURCE or name == "__pycache__" or name.endswith(".egg-info") or name.startswith(".venv")}

    source = tmp_path / "src"
    shutil.copytree(REPO, source, ignore=ignore, symlinks=True)
    return source


def _run(command: list[str], *, cwd: Path, env: dict[str, str], timeout: float) -> subprocess.CompletedProcess:
    process = subprocess.run(command, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert process.returncode == 0, f"{' '.join(map(str, command))} failed ({process.returncode}):\n{process.stdout[-3000:]}\n{process.stderr[-3000:]}"
    return process


def test_the_wheel_carries_the_bundled_datasets_and_every_module(tmp_path) -> None:
    assert bundled_datasets().resolve() == DATASETS.resolve()
    mcaps = sorted(DATASETS.glob("*.mcap"))
    assert mcaps

    source, env = _copy_project(tmp_path), _offline_env(tmp_path)
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", str(tmp_path / "wheel"), str(source)], cwd=tmp_path, env=env, timeout=120)
    [wheel] = (tmp_path / "wheel").glob("imitation_mcap-*.whl")
    with zipfile.ZipFile(wheel) as archive:
        names = set(archive.namelist())
        for mcap in mcaps:
            assert archive.read(f"imitation/datasets/{mcap.name}") == mcap.read_bytes()
        entry_points = next(archive.read(name).decode() for name in names if name.endswith(".dist-info/entry_points.txt"))
        archive.extractall(tmp_path / "installed")
    assert "cli.py" in names and "imitation = cli:main" in entry_points
    modules = {path.relative_to(source).as_posix() for path in (source / "imitation").rglob("*.py") if "__pycache__" not in path.parts}
    assert modules - names == set(), "modules missing from the wheel (a package that setup.py's list does not find?)"
    assert not any(name.startswith("datasets/") for name in names), "a top-level datasets/ would shadow Hugging Face `datasets`"

    # The installed layout: bundled_datasets() finds the package data, with no checkout beside it.
    lookup = _run([sys.executable, "-S", "-c", "from imitation.bundled import bundled_datasets; print(bundled_datasets())"],
                  cwd=tmp_path, env={**env, "PYTHONPATH": str(tmp_path / "installed")}, timeout=60)
    assert Path(lookup.stdout.strip()).resolve() == (tmp_path / "installed" / "imitation" / "datasets").resolve()


def _fresh_venv(tmp_path: Path) -> Path:
    """A new virtualenv from the base interpreter, with the heavy dependencies borrowed from this
    one through a .pth file, but not the project: the .pth names a folder of links to every entry
    of this site-packages except the project's own (its editable-install finder and metadata)."""
    version = f"{sys.version_info.major}.{sys.version_info.minor}"
    base = Path(sys.base_prefix) / "bin" / f"python{version}"
    if not base.is_file():
        pytest.skip(f"no base interpreter at {base}")
    deps = tmp_path / "deps"
    deps.mkdir()
    for site in dict.fromkeys([sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]]):
        for entry in Path(site).iterdir():
            stem = entry.name.split(".")[0].split("-")[0]
            if stem in ("imitation", "imitation_mcap", "cli", "__pycache__") or entry.name.startswith("__editable__") or entry.suffix == ".pth":
                continue
            if not (deps / entry.name).exists():
                (deps / entry.name).symlink_to(entry)
    venv = tmp_path / "venv"
    _run([str(base), "-m", "venv", "--without-pip", str(venv)], cwd=tmp_path, env=_offline_env(tmp_path), timeout=120)
    [site_packages] = (venv / "lib").glob("python*/site-packages")
    (site_packages / "_borrowed_dependencies.pth").write_text(f"{deps}\n")
    return venv


@pytest.mark.slow
def test_pip_install_then_demo_outside_the_source_tree(tmp_path) -> None:
    venv, env = _fresh_venv(tmp_path), _offline_env(tmp_path)
    python = str(venv / "bin" / "python")
    before = _run([python, "-c", "import importlib.util as u; print([u.find_spec(m) for m in ('imitation', 'cli')])"], cwd=tmp_path, env=env, timeout=60)
    assert before.stdout.strip() == "[None, None]", "the fresh venv sees the project before installing it"

    # pip comes from the borrowed dependencies; it installs into the running (fresh) environment.
    _run([python, "-m", "pip", "install", "--no-deps", "--no-build-isolation", "-q", str(_copy_project(tmp_path))], cwd=tmp_path, env=env, timeout=300)
    where = _run([python, "-c", "import imitation, cli; print(imitation.__file__); print(cli.__file__)"], cwd=tmp_path, env=env, timeout=60)
    assert all(Path(line).is_relative_to(venv) for line in where.stdout.split()), where.stdout

    empty = tmp_path / "empty"
    empty.mkdir()
    _run([str(venv / "bin" / "imitation"), "demo", "--quick", "--quiet", "--out", "demo-out"], cwd=empty, env=env, timeout=900)
    report = (empty / "demo-out" / "report.md").read_text()
    for mcap in DATASETS.glob("*.mcap"):
        assert f"| {mcap.name} |" in report
