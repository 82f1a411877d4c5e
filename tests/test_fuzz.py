"""The short fuzzing run of `make test`: a few hundred seeded mutations per target (tools/fuzz.py
runs 10,000 each; figures in bench/RESULTS.md). Every input must load, load a salvaged prefix, or
be refused with an ImitationError; the counts also show the mutations reach both outcomes."""

from __future__ import annotations

import importlib.util
import sys

import pytest
from support import REPO, TESTDATA

spec = importlib.util.spec_from_file_location("imitation_fuzz", REPO / "tools" / "fuzz.py")
fuzz = importlib.util.module_from_spec(spec)
sys.modules["imitation_fuzz"] = fuzz
spec.loader.exec_module(fuzz)

# Inputs per target, sized so the whole run takes about a minute on 2 cores, well under 90 s (measured in bench/RESULTS.md).
COUNTS = {"demo": 200, "run": 500, "npz": 600, "lerobot": 30, "ros2": 200, "ros1": 300, "sqlite": 60, "map": 120, "sb3": 300, "cli": 15}
SEED = 0  # the long run's seed: these are its first inputs, so each was vetted there too


def test_every_target_has_a_short_run() -> None:
    assert set(COUNTS) == set(fuzz.TARGETS)


@pytest.mark.parametrize("name", list(COUNTS))
def test_fuzzed_inputs_load_or_fail_with_one_imitation_error(name: str, tmp_path) -> None:
    if fuzz.TARGETS[name].needs_testdata and not TESTDATA.is_dir():
        pytest.skip(f"third-party test data not found at {TESTDATA}")
    report = fuzz.fuzz(name, count=COUNTS[name], seed=SEED, time_limit=60, failures_dir=tmp_path)
    figures = report.as_dict()
    assert not report.failures, "\n".join(f"input {f.index}: {f.where}: {f.error} (saved in {f.saved})" for f in report.failures[:10])
    accepted = sum(report.outcomes.values())
    assert report.inputs == COUNTS[name] == accepted + report.refused
    # The mutations must exercise both paths: some inputs still load (or salvage), many are refused.
    assert report.refused >= 0.05 * report.inputs and accepted >= 0.02 * report.inputs, figures
