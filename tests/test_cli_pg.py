"""`train pg` from the command line: its run directory, `eval policy` on it (a softmax policy
through the CLI, a linear Gaussian one through the job functions), and its help text against
PGConfig's defaults and the presets (resume is tested on the learner, in
tests/algorithms/test_policy_gradient.py)."""

from __future__ import annotations

import dataclasses
import json
import re

import pytest
from support import run_cli_many
from test_cli import last_json

from imitation.algorithms.policy_gradient import PGConfig
from imitation.jobs.pg import PG_PRESETS


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> tuple:
    """A short actor-critic run on CartPole and `eval policy` on it, in one process."""
    out = tmp_path_factory.mktemp("pg") / "cartpole"
    argvs = [
        [
            "train",
            "pg",
            "--env",
            "CartPole-v1",
            "--estimator",
            "actor-critic",
            "--n-step",
            "5",
            "--steps",
            "1000",
            "--batch-steps",
            "500",
            "--hidden",
            "16",
            "--seed",
            "1",
            "--quiet",
            "--json",
            "--out",
            out,
        ],
        ["eval", "policy", out, "--env", "CartPole-v1", "--episodes", "2", "--json"],
    ]
    train, evaluate = run_cli_many([[str(a) for a in argv] for argv in argvs], timeout=600)
    return out, train, evaluate


def test_train_pg_writes_a_run_that_eval_policy_reads(runs) -> None:
    out, train, evaluate = runs
    result = last_json(train)
    assert result["run"] == str(out) and result["estimator"] == "actor-critic" and result["n_step"] == 5
    assert result["steps"] >= 1000 and result["batches"] >= 1
    names = {path.name for path in out.iterdir()}
    assert {"config.json", "model.safetensors", "metrics.json", "progress.csv", "learning_curve.png"} <= names
    config = json.loads((out / "config.json").read_text())
    assert config["kind"] == "pg" and config["pg"]["estimator"] == "actor-critic" and config["pg"]["seed"] == 1
    assert config["policy"]["hidden_sizes"] == [16]
    evaluation = last_json(evaluate)
    assert evaluation["episodes"] == 2 and evaluation["mean_return"] >= 1
    # The run's own final evaluation is eval policy's (deterministic, 10 episodes from seed 10000).
    assert result["eval"]["episodes"] == 10


def test_a_linear_gaussian_run_saves_a_policy_eval_policy_loads(tmp_path) -> None:
    """The job on Pendulum with a linear Gaussian policy (the preset's normalisers on), then
    `eval policy`'s own function on the run directory."""
    from imitation.jobs.evaluate_policy import eval_policy_job
    from imitation.jobs.evaluate_policy_config import PolicyEvaluationConfig
    from imitation.jobs.pg import pg_config, pg_job

    config = pg_config("Pendulum-v1", estimator="reward-to-go", total_steps=400, batch_steps=200, n_envs=1, hidden_sizes=[])
    assert config.normalize_observations and config.normalize_rewards
    result = pg_job(config, tmp_path / "pendulum", progress=False)
    assert result["steps"] == 400 and result["batches"] == 2
    saved = json.loads((tmp_path / "pendulum" / "config.json").read_text())["policy"]
    assert saved["hidden_sizes"] == [] and saved["normalize_observations"] is True
    evaluation = eval_policy_job(str(tmp_path / "pendulum"), "Pendulum-v1", PolicyEvaluationConfig(episodes=1))
    assert evaluation["episodes"] == 1 and -2000 < evaluation["mean_return"] < 0


def test_train_pg_help_names_the_configs_own_defaults_and_the_presets() -> None:
    """No argparse defaults (an absent flag leaves the preset's or PGConfig's), so the help text
    says the default: the last value it names is PGConfig's, and the per-env step counts it
    names are the presets'."""
    from cli import make_parser
    from imitation.flags import flag_name, flagged

    parser = make_parser()
    pg = parser._subparsers._group_actions[0].choices["train"]._subparsers._group_actions[0].choices["pg"]
    helps = {option: action.help for action in pg._actions for option in action.option_strings}
    defaults = {
        f.name: f.default if f.default_factory is dataclasses.MISSING else f.default_factory()
        for f in dataclasses.fields(PGConfig)
    }
    for field, flag in ((field.name, flag_name(field)) for field in flagged(PGConfig) if field.name != "env_id"):
        shown = re.search(r"\(default: (.+)\)$", helps[flag])
        assert shown is not None, flag
        value = defaults[field]
        expected = "none" if value is None else ",".join(map(str, value)) if isinstance(value, list) else str(value)
        last = re.split(r", else |; else ", shown[1])[-1]
        assert last.startswith(expected), (flag, last, expected)
        assert pg.get_default(flag.lstrip("-").replace("-", "_")) is None, flag
    steps = helps["--steps"]
    assert f"{PG_PRESETS['CartPole-v1']['*']['total_steps']} for CartPole-v1" in steps
    assert f"{PG_PRESETS['CartPole-v1']['actor-critic']['total_steps']} with actor-critic" in steps
    assert f"{PG_PRESETS['Pendulum-v1']['*']['total_steps']} for Pendulum-v1" in steps
    assert f"{PG_PRESETS['Pendulum-v1']['actor-critic']['total_steps']} with actor-critic" in steps
    assert f"{PG_PRESETS['Pendulum-v1']['actor-critic']['rollout_steps']} for Pendulum-v1" in helps["--rollout-steps"]


def test_a_batch_size_given_means_whole_episodes_over_the_presets_rollouts() -> None:
    """Pendulum's actor-critic preset runs 2-step rollouts; `--batch-steps` alone asks for batches
    of whole episodes, and `--rollout-steps` overrides the preset's."""
    from imitation.jobs.pg import pg_config

    assert pg_config("Pendulum-v1", estimator="actor-critic").rollout_steps == 2
    assert pg_config("Pendulum-v1", estimator="actor-critic", batch_steps=400).rollout_steps is None
    assert pg_config("Pendulum-v1", estimator="actor-critic", batch_steps=400, rollout_steps=5).rollout_steps == 5
    assert pg_config("Pendulum-v1", estimator="baseline").rollout_steps is None


def test_a_rollout_run_is_a_run_eval_policy_reads(tmp_path) -> None:
    """Pendulum's actor-critic preset (8 copies × 2-step rollouts) for 160 steps: ten batches of
    exactly 16 steps, and a run directory `eval policy` loads."""
    from imitation.jobs.evaluate_policy import eval_policy_job
    from imitation.jobs.evaluate_policy_config import PolicyEvaluationConfig
    from imitation.jobs.pg import pg_config, pg_job

    config = pg_config("Pendulum-v1", estimator="actor-critic", total_steps=160, hidden_sizes=[8])
    result = pg_job(config, tmp_path / "a2c", progress=False)
    assert result["steps"] == 160 and result["batches"] == 10
    assert json.loads((tmp_path / "a2c" / "config.json").read_text())["pg"]["rollout_steps"] == 2
    assert eval_policy_job(str(tmp_path / "a2c"), "Pendulum-v1", PolicyEvaluationConfig(episodes=1))["episodes"] == 1
