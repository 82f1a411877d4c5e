"""Small hostile files and misbehaving servers (tools/hostile_inputs.py builds them) are refused
in one line, exit 1, within 2 CPU seconds (a server's cases: 2 s of wall time as well) and 200 MB
beyond what the same command costs on a trivially bad input."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest
from support import REPO, TESTDATA

spec = importlib.util.spec_from_file_location("hostile_inputs", REPO / "tools" / "hostile_inputs.py")
hostile = importlib.util.module_from_spec(spec)
sys.modules["hostile_inputs"] = hostile
spec.loader.exec_module(hostile)

CASES = {case.name: case for case in hostile.CASES}


@pytest.fixture(scope="module")
def baselines(tmp_path_factory) -> dict[str, object]:
    return {name: hostile.measure(CASES[name], tmp_path_factory.mktemp("baseline")) for name in {case.baseline for case in CASES.values()}}


@pytest.mark.parametrize("name", [name for name, case in CASES.items() if case.baseline != name])
def test_a_small_hostile_input_is_refused_in_one_line_cheaply(name: str, baselines, tmp_path: Path) -> None:
    case = CASES[name]
    if case.testdata and not TESTDATA.is_dir():
        pytest.skip("needs ../shared/testdata (a real ROS 2 bag to convert)")
    outcome = hostile.measure(case, tmp_path)
    base = baselines[case.baseline]
    assert outcome.returncode == 1, outcome
    assert outcome.message.startswith("error: ") and case.expect in outcome.message, outcome.message
    assert outcome.cpu_seconds - base.cpu_seconds < 2.0, (outcome.cpu_seconds, base.cpu_seconds)
    assert outcome.peak_rss_mb - base.peak_rss_mb < 200, (outcome.peak_rss_mb, base.peak_rss_mb)
    if case in hostile.SERVER_CASES:  # waiting on a server costs no CPU: its time is wall time
        assert outcome.seconds - base.seconds < 2.0, (outcome.seconds, base.seconds)


def test_a_bound_raised_with_limit_lets_real_data_through(tmp_path: Path) -> None:
    """The zeros file is real data DemoWriter wrote: `--limit` (or IMITATION_LIMITS) admits it."""
    import os
    import subprocess

    zeros = hostile._zeros_file(tmp_path)
    refused = hostile.run(["info", str(zeros)])
    assert refused[0] == 1 and "expansion_ratio" in refused[1]
    assert hostile.run(["--limit", "expansion_ratio=1000000", "info", str(zeros)])[0] == 0
    inherited = subprocess.run([sys.executable, str(REPO / "cli.py"), "info", str(zeros)], capture_output=True, text=True,
                               env={**os.environ, "IMITATION_LIMITS": "expansion_ratio=1000000"})
    assert inherited.returncode == 0, inherited.stderr


def test_image_bounds_raised_with_limit_let_real_frames_through(tmp_path: Path) -> None:
    """Black frames and a many-scan JPEG are real pictures Pillow wrote: `--limit` admits them."""
    black = hostile._black_frames_demo(tmp_path, "black.mcap", 12)  # 13 frames, 81 MB decoded from 9 KB
    refused = hostile.run(["info", str(black)])
    assert refused[0] == 1 and "image_expansion_ratio" in refused[1]
    assert hostile.run(["--limit", "image_expansion_ratio=100000", "info", str(black)])[0] == 0
    scans = hostile._many_scans_demo(tmp_path, 600, 1)
    refused = hostile.run(["info", str(scans)])
    assert refused[0] == 1 and "jpeg_scans" in refused[1]
    assert hostile.run(["--limit", "jpeg_scans=600", "info", str(scans)])[0] == 0
