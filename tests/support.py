"""Paths and helpers shared by the tests."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Sequence

REPO = Path(__file__).resolve().parent.parent
TESTDATA = REPO.parent / "shared" / "testdata"
DATASETS = REPO / "datasets"


def run_cli(*args: str, timeout: float = 120, **kwargs) -> subprocess.CompletedProcess:
    """Run `python cli.py ARGS` in a fresh process, as a user would."""
    return subprocess.run(
        [sys.executable, str(REPO / "cli.py"), *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        cwd=kwargs.pop("cwd", REPO),
        **kwargs,
    )


# Runs cli.main(argv) for each argv in one process, exactly as `python cli.py ARGV` does after
# startup (argparse exits included): the CLI's parsing, dispatch, error handling and exit code,
# without paying a fresh interpreter and torch import (~2 s) per case.
_BATCH_RUNNER = r"""
import contextlib, io, json, sys, traceback, warnings
cases_path, results_path = sys.argv[1], sys.argv[2]
import cli
results = []
for argv in json.load(open(cases_path)):
    warnings.filterwarnings("default", append=True)  # forget which warnings were shown: each case starts afresh
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = cli.main(argv)
        except SystemExit as exit:
            code = exit.code if isinstance(exit.code, int) else (0 if exit.code is None else 1)
        except BaseException:
            traceback.print_exc()
            code = 1
    results.append({"returncode": code, "stdout": out.getvalue(), "stderr": err.getvalue()})
json.dump(results, open(results_path, "w"))
"""


def run_cli_many(cases: Sequence[Sequence[str]], *, timeout: float = 600, env: dict[str, str] | None = None) -> list[subprocess.CompletedProcess]:
    """`run_cli` for many argument lists at once, in one fresh process (see _BATCH_RUNNER)."""
    with tempfile.TemporaryDirectory(prefix="imitation-cli-batch-") as folder:
        cases_path, results_path = Path(folder) / "cases.json", Path(folder) / "results.json"
        cases_path.write_text(json.dumps([list(map(str, argv)) for argv in cases]))
        process = subprocess.run(
            [sys.executable, "-c", _BATCH_RUNNER, str(cases_path), str(results_path)],
            capture_output=True, text=True, timeout=timeout, cwd=REPO,
            env={**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), str(REPO / "tests")]), **(env or {})},
        )
        if process.returncode != 0 or not results_path.exists():
            raise RuntimeError(f"the batch runner failed ({process.returncode}): {process.stderr[-3000:]}")
        results = json.loads(results_path.read_text())
    return [subprocess.CompletedProcess(["imitation", *argv], r["returncode"], r["stdout"], r["stderr"]) for argv, r in zip(cases, results)]


# The turtlesim map: the pose as the observation, the keyboard teleop's command as the action.
TURTLE_MAP = {
    "rate_hz": 10,
    "time": "log",
    "observation": [{"topic": "/turtle1/pose", "fields": ["x", "y", "theta", "linear_velocity", "angular_velocity"]}],
    "action": [{"topic": "/turtle1/cmd_vel", "fields": ["linear.x", "angular.z"]}],
    "episodes": {"split": "file"},
    "env_id": None,
}


def write_map(folder: Path, data: dict, name: str = "map.yaml") -> Path:
    """A conversion map as YAML in `folder`."""
    import yaml

    path = folder / name
    path.write_text(yaml.safe_dump(data))
    return path


def random_policy_return(env_id: str) -> float:
    """A uniform random policy's mean return over 10 episodes (seeds 0-9): the 0 of normalised returns."""
    from imitation.envs.make import make_env
    from imitation.evaluation.policy import evaluate_policy

    env = make_env(env_id)
    env.action_space.seed(0)
    return evaluate_policy(lambda observation: env.action_space.sample(), env, episodes=10, seed=0)["mean_return"]
