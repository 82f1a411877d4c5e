"""Our files open in standard MCAP tooling: pymcap-cli's info, doctor and cat."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from support import DATASETS

PYMCAP = Path(sys.executable).parent / "pymcap-cli"


@pytest.fixture
def pymcap() -> str:
    tool = str(PYMCAP) if PYMCAP.exists() else shutil.which("pymcap-cli")
    if tool is None:
        pytest.skip("pymcap-cli is not installed (it is a dev dependency: pip install -e .[dev])")
    return tool


def run(tool: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([tool, *args], capture_output=True, text=True, timeout=120, env={"COLUMNS": "200", "PATH": "/usr/bin:/bin"})


@pytest.mark.parametrize("name", ["CartPole-v1", "Pendulum-v1"])
def test_pymcap_info_reads_our_files(pymcap: str, name: str) -> None:
    result = run(pymcap, "info", str(DATASETS / f"{name}.mcap"))
    assert result.returncode == 0, result.stderr
    for topic in ("/observation", "/action", "/reward", "/episode"):
        assert topic in result.stdout
    assert "imitation" in result.stdout


def test_pymcap_doctor_finds_no_errors(pymcap: str) -> None:
    result = run(pymcap, "doctor", str(DATASETS / "CartPole-v1.mcap"))
    assert result.returncode == 0, result.stdout + result.stderr
    assert "passed MCAP doctor checks" in result.stdout


def test_pymcap_cat_shows_episode_markers(pymcap: str) -> None:
    result = run(pymcap, "cat", str(DATASETS / "CartPole-v1.mcap"), "--topic", "/episode")
    assert result.returncode == 0, result.stderr
    markers = [json.loads(line)["message"] for line in result.stdout.splitlines() if line.strip()]
    assert [marker["index"] for marker in markers] == list(range(25))
    assert all(marker["length"] == 500 for marker in markers)
