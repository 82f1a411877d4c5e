"""Discrete actions that do not start at 0, through the CLI: `Discrete(3, start=1)` and
`MultiDiscrete([3, 2], start=[1, -1])` (tests/shifted_envs.py). A PPO expert is trained, its
episodes recorded, and BC and DAgger learn from them; each policy must act in env actions
(index + start), which only a correct mapping both ways scores in full."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from shifted_envs import EPISODE_STEPS
from support import run_cli_many


@pytest.mark.parametrize("env_name, components", [("ShiftedDiscrete-v0", 1), ("ShiftedMultiDiscrete-v0", 2)])
def test_shifted_discrete_actions_learn_and_act_through_record_bc_dagger_and_eval(env_name: str, components: int, tmp_path: Path) -> None:
    env = ["--env", f"shifted_envs:{env_name}"]
    expert, demos = tmp_path / "expert", tmp_path / "demos.mcap"
    cases = [
        ["train", "ppo", *env, "--steps", "8192", "--quiet", "--out", expert],
        ["record", *env, "--expert", expert, "--episodes", "10", "--quiet", "--out", demos],
        ["train", "bc", *env, "--demos", demos, "--epochs", "100", "--quiet", "--out", tmp_path / "bc"],
        ["train", "dagger", *env, "--expert", expert, "--rounds", "2", "--quiet", "--out", tmp_path / "dagger"],
        *(["eval", "policy", tmp_path / run, *env, "--episodes", "5", "--json"] for run in ("expert", "bc", "dagger")),
    ]
    results = run_cli_many(cases)
    for case, result in zip(cases, results):
        assert result.returncode == 0, (case, result.stderr[-2000:])
    best = float(EPISODE_STEPS * components)
    returns = {run: json.loads(result.stdout)["mean_return"] for run, result in zip(("expert", "bc", "dagger"), results[-3:])}
    assert returns == {"expert": best, "bc": best, "dagger": best}
