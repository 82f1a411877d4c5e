"""`train ppo`, `eval policy` and `record --expert RUN_DIR` from the command line, and their errors."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest
from support import run_cli
from test_cli import assert_one_line_error, last_json

from imitation.rewards import make_reward_model, reward_tensors
from imitation.runs import RunWriter


@pytest.fixture(scope="module")
def ppo_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("ppo") / "cartpole"
    result = run_cli("train", "ppo", "--env", "CartPole-v1", "--steps", "4096", "--seed", "1", "--out", str(out), "--json", timeout=300)
    return out, last_json(result)


def test_train_ppo_writes_a_complete_run_directory(ppo_run) -> None:
    out, result = ppo_run
    assert result["run"] == str(out) and result["steps"] == 4096 and result["objective"] == "clip"
    assert {"mean_return", "std_return", "episodes"} <= set(result["eval"])
    names = {path.name for path in out.iterdir()}
    assert {"config.json", "model.safetensors", "metrics.json", "progress.csv", "learning_curve.png", "tb"} <= names
    assert not {name for name in names if name.startswith("checkpoint")}, "only an interrupted run keeps its checkpoint"
    config = json.loads((out / "config.json").read_text())
    assert config["kind"] == "ppo" and config["ppo"]["n_envs"] == 8 and config["policy"]["hidden_sizes"] == [64, 64]
    rows = (out / "progress.csv").read_text().splitlines()
    assert rows[0].startswith("step,return") and len(rows) == 1 + 4096 // 256
    assert not out.with_name("cartpole.partial").exists()


def test_eval_policy_json(ppo_run) -> None:
    out, _ = ppo_run
    result = last_json(run_cli("eval", "policy", str(out), "--env", "CartPole-v1", "--episodes", "3", "--json"))
    assert result["episodes"] == 3 and len(result["returns"]) == 3
    assert result["mean_return"] == pytest.approx(np.mean(result["returns"]))
    assert {"mean_return", "std_return", "min_return", "max_return"} <= set(result)


def test_a_ppo_run_is_an_expert_for_record(ppo_run, tmp_path) -> None:
    out, _ = ppo_run
    demos = tmp_path / "from_ppo.mcap"
    recorded = last_json(run_cli("record", "--env", "CartPole-v1", "--expert", str(out), "--episodes", "2", "--out", str(demos), "--json"))
    evaluated = last_json(run_cli("eval", "policy", str(out), "--env", "CartPole-v1", "--episodes", "2", "--json"))
    assert recorded["mean_return"] == pytest.approx(evaluated["mean_return"])  # same seeds, deterministic policy


def test_policy_for_another_env_is_refused(ppo_run, tmp_path) -> None:
    out, _ = ppo_run
    assert_one_line_error(run_cli("eval", "policy", str(out), "--env", "Pendulum-v1"), "observation space", "does not match")
    assert_one_line_error(run_cli("record", "--env", "Acrobot-v1", "--expert", str(out), "--out", str(tmp_path / "x.mcap")), "does not match")


def test_bad_run_directories(tmp_path) -> None:
    assert_one_line_error(run_cli("eval", "policy", str(tmp_path / "nothing"), "--env", "CartPole-v1"), "not a run directory")
    assert_one_line_error(run_cli("train", "ppo", "--env", "CartPole-v1", "--reward", str(tmp_path), "--out", str(tmp_path / "r")), "not a finished run directory")


def test_reward_must_be_a_reward_model(ppo_run, tmp_path) -> None:
    out, _ = ppo_run
    result = run_cli("train", "ppo", "--env", "CartPole-v1", "--steps", "512", "--reward", str(out), "--out", str(tmp_path / "r"))
    assert_one_line_error(result, "not a reward model")
    assert not (tmp_path / "r").exists() and not (tmp_path / "r.partial").exists()


def write_reward_run(path, observation_space, action_space) -> None:
    model = make_reward_model(observation_space, action_space, inputs="s", hidden_sizes=[8])
    run = RunWriter(path, config={"kind": "reward", "env_id": "X", "reward": model.config.to_json()}, tensorboard=False)
    run.save_weights(reward_tensors(model))
    run.finish({})


def test_reward_model_shapes_must_match_the_env(tmp_path) -> None:
    write_reward_run(tmp_path / "reward", gym.spaces.Box(-1, 1, (3,), np.float32), gym.spaces.Box(-2, 2, (1,), np.float32))
    result = run_cli("train", "ppo", "--env", "CartPole-v1", "--steps", "512", "--reward", str(tmp_path / "reward"), "--out", str(tmp_path / "r"))
    assert_one_line_error(result, "reward model's observation space Box(float32, (3,)) does not match the env's Box(float32, (4,))")


def test_train_on_a_learned_reward_from_the_cli(tmp_path) -> None:
    env = gym.make("Pendulum-v1")
    write_reward_run(tmp_path / "reward", env.observation_space, env.action_space)
    result = last_json(run_cli("train", "ppo", "--env", "Pendulum-v1", "--steps", "4096", "--reward", str(tmp_path / "reward"), "--out", str(tmp_path / "r"), "--json", timeout=300))
    header = (tmp_path / "r" / "progress.csv").read_text().splitlines()[0]
    assert "optimised_return" in header and result["eval"]["episodes"] == 10


def test_unknown_env_and_bad_steps(tmp_path) -> None:
    assert_one_line_error(run_cli("train", "ppo", "--env", "Nope-v9", "--out", str(tmp_path / "r")), "Nope-v9")
    assert_one_line_error(run_cli("train", "ppo", "--env", "CartPole-v1", "--steps", "10", "--out", str(tmp_path / "r")), "less than one rollout")
