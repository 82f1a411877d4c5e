"""`eval reward`: the true reward scores EPIC ≈ 0 and retrains to ≈ 1; the controls do not."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from support import DATASETS, run_cli, run_cli_many

import imitation.envs  # noqa: F401 - registers the imitation/ envs
from imitation.envs.make import make_env
from imitation.envs.tabular import _GRID_WEIGHTS
from imitation.jobs.run_directory import save_reward_run
from imitation.rewards import make_reward_model

GRIDWORLD = "imitation/GridWorld8x8Slippery-v0"
CARTPOLE = "imitation/CartPoleFixedHorizon-v0"


def true_gridworld_reward(path):
    """A linear reward on the gridworld's cell-type features with the true weights: the true reward itself."""
    env = make_env(GRIDWORLD)
    mdp = env.unwrapped.mdp
    model = make_reward_model(env.observation_space, env.action_space, feature_table=mdp.features, hidden_sizes=[])
    with torch.no_grad():
        model.net[-1].weight.copy_(torch.as_tensor(_GRID_WEIGHTS, dtype=torch.float32)[None])
        model.net[-1].bias.zero_()
    return save_reward_run(model, path, env_id=GRIDWORLD, source="test: true reward")


def true_cartpole_reward(path):
    """R(s, a, s') = 1 − failed(s'), as a linear reward on (s, a, s'): the fixed-horizon CartPole's true reward."""
    env = make_env(CARTPOLE)
    model = make_reward_model(env.observation_space, env.action_space, hidden_sizes=[], inputs="sas")
    with torch.no_grad():
        weight = torch.zeros_like(model.net[-1].weight)
        weight[0, 5 + 2 + 4] = -1.0  # s (5 values), a one-hot (2), then s'[4], the failure flag
        model.net[-1].weight.copy_(weight)
        model.net[-1].bias.fill_(1.0)
    return save_reward_run(model, path, env_id=CARTPOLE, source="test: true reward")


def test_tabular_true_reward_is_exact_and_controls_are_not(tmp_path) -> None:
    run = true_gridworld_reward(tmp_path / "true-reward")
    result = run_cli("eval", "reward", str(run), "--env", GRIDWORLD, "--out", str(tmp_path / "eval"), "--json", "--quiet")
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout.strip().splitlines()[-1])
    assert report["epic"] < 1e-6 and report["pearson"] > 1 - 1e-9
    assert report["retrain"]["normalized"] == pytest.approx(1.0, abs=1e-9)
    assert report["controls"]["constant"]["normalized"] == pytest.approx(0.0, abs=1e-9)
    assert report["controls"]["constant"]["epic"] == pytest.approx(np.sqrt(0.5))
    assert report["controls"]["random"]["epic"] > 0.3 and report["controls"]["random"]["normalized"] < 0.5
    written = sorted(p.name for p in (tmp_path / "eval").iterdir())
    assert {"metrics.json", "report.md", "report.html", "reward_maps.png", "reward_scatter.png"} <= set(written)
    text = (tmp_path / "eval" / "report.md").read_text()
    assert "| recovered reward | 0.000 | 1.000 |" in text and "![reward_maps](reward_maps.png)" in text


def test_continuous_true_reward_has_epic_near_zero(tmp_path) -> None:
    """Sampled EPIC over demos, rollouts and uniform transitions; a short retraining checks the
    whole path runs (the learning result is the slow test's job)."""
    run = true_cartpole_reward(tmp_path / "true-reward")
    result = run_cli(
        "eval", "reward", str(run), "--env", CARTPOLE, "--demos", str(DATASETS / "CartPoleFixedHorizon-v0.mcap"),
        "--retrain-steps", "4096", "--seeds", "1", "--out", str(tmp_path / "eval"), "--json", "--quiet", timeout=300,
    )
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout.strip().splitlines()[-1])
    assert report["epic"] < 0.02 and report["pearson"] > 0.99
    assert report["controls"]["random"]["epic"] > 0.3
    assert report["references"]["expert_return"] == pytest.approx(500.0)
    assert len(report["retrain"]["seed_returns"]) == 1 and report["retrain"]["steps"] == 4096
    assert {"reward_scatter.png", "state_slices.png", "retrain_returns.png", "report.md"} <= {p.name for p in (tmp_path / "eval").iterdir()}


@pytest.mark.slow
def test_continuous_true_reward_retrains_to_the_expert_and_the_random_control_does_not(tmp_path) -> None:
    run = true_cartpole_reward(tmp_path / "true-reward")
    result = run_cli(
        "eval", "reward", str(run), "--env", CARTPOLE, "--demos", str(DATASETS / "CartPoleFixedHorizon-v0.mcap"),
        "--seeds", "1", "--out", str(tmp_path / "eval"), "--json", "--quiet", timeout=1200,
    )
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout.strip().splitlines()[-1])
    assert report["retrain"]["normalized"] > 0.9
    assert report["controls"]["random"]["normalized"] < 0.5 and report["controls"]["constant"]["normalized"] < 0.5


def test_bad_input_is_one_line(tmp_path) -> None:
    not_a_reward = run_cli("eval", "reward", str(tmp_path), "--env", GRIDWORLD)
    assert not_a_reward.returncode == 1 and not_a_reward.stderr.count("\n") == 1 and "not a finished run directory" in not_a_reward.stderr
    run = true_gridworld_reward(tmp_path / "true-reward")
    wrong_env = run_cli("eval", "reward", str(run), "--env", "CartPole-v1")
    assert wrong_env.returncode == 1 and wrong_env.stderr.count("\n") == 1 and "observation space" in wrong_env.stderr, wrong_env.stderr
    assert not (run / "eval-reward").exists() and not (run / "eval-reward.partial").exists()


def test_a_constant_true_reward_gets_no_epic_and_says_why(tmp_path) -> None:
    """MountainCar pays -1 every step: no reward can be nearer to or further from that than
    another, so EPIC and Pearson are undefined and `eval reward` says so instead of scoring."""
    env = make_env("MountainCar-v0")
    run = save_reward_run(make_reward_model(env.observation_space, env.action_space), tmp_path / "reward", env_id="MountainCar-v0", source="test")
    result = run_cli(
        "eval", "reward", str(run), "--env", "MountainCar-v0", "--demos", str(DATASETS / "MountainCar-v0.mcap"), "--retrain-steps", "0",
        "--out", str(tmp_path / "eval"), "--quiet",
    )
    assert result.returncode == 0, result.stderr
    assert "EPIC n/a, Pearson n/a" in result.stdout and "note: the true reward is constant on the coverage batch" in result.stdout
    metrics = json.loads((tmp_path / "eval" / "metrics.json").read_text())
    assert metrics["epic"] is None and metrics["coverage"]["true_reward"].startswith("constant")
    assert all(control["epic"] is None for control in metrics["controls"].values())
    assert "The true reward is constant" in (tmp_path / "eval" / "report.md").read_text()


def test_eval_reward_estimates_its_time_reports_progress_to_a_log_and_shares_eval_policys_reference(tmp_path) -> None:
    """stderr is a pipe here, as in a batch job: an estimate first, then progress lines. The
    random-policy reference is computed one way, and both `eval reward` and `eval policy` name it."""
    run = true_cartpole_reward(tmp_path / "true-reward")
    demos = str(DATASETS / "CartPoleFixedHorizon-v0.mcap")
    reward = run_cli("eval", "reward", str(run), "--env", CARTPOLE, "--demos", demos, "--retrain-steps", "512", "--seeds", "1",
                     "--out", str(tmp_path / "eval"), "--json", timeout=300)
    assert reward.returncode == 0, reward.stderr
    assert "[eval reward] retraining PPO from scratch: 3 rewards × 1 seed(s) × 512 steps, 2 at a time; about" in reward.stderr
    assert "[retrain] run 3/3" in reward.stderr
    report = json.loads(reward.stdout.strip().splitlines()[-1])
    assert report["retrain"]["estimated_seconds"] > 0
    reward_reference = report["references"]
    retrained = tmp_path / "eval" / "retrain" / "learned-seed0"
    policy, policy_json = run_cli_many([
        ["eval", "policy", str(retrained), "--env", CARTPOLE, "--episodes", "3", "--seed", "7", "--demos", demos],
        ["eval", "policy", str(retrained), "--env", CARTPOLE, "--episodes", "3", "--seed", "7", "--demos", demos, "--json"],
    ])
    assert policy.returncode == 0, policy.stderr
    policy_reference = json.loads(policy_json.stdout.strip().splitlines()[-1])["reference"]
    assert policy_reference["random_return"] == reward_reference["random_return"]
    assert policy_reference["source"] == reward_reference["source"]
    assert "uniform random actions (10 episodes, seeds 10000-10009)" in policy.stdout


def test_the_time_estimate_leaves_torchs_generator_as_it_found_it() -> None:
    """The probe's PPO seeds torch; what `eval reward` draws afterwards must not depend on it."""
    from imitation.jobs.evaluate_reward import _estimate_seconds
    from imitation.jobs.presets import ppo_config

    env = make_env(CARTPOLE)
    reward = make_reward_model(env.observation_space, env.action_space, hidden_sizes=[8], inputs="sas")
    torch.manual_seed(1234)
    before = torch.get_rng_state()
    seconds = _estimate_seconds(ppo_config(CARTPOLE, learned_reward=True, total_steps=4096, seed=7), reward, runs=3, workers=1)
    assert seconds > 0
    assert torch.equal(torch.get_rng_state(), before)


def test_a_pixel_reward_is_refused_in_one_line_naming_what_is_unsupported(tmp_path) -> None:
    import gymnasium as gym

    # The reward GCL learns on `record --pixels 36x36 --grayscale --frame-stack 2` demos of CartPole.
    frames = gym.spaces.Box(0, 255, (2, 36, 36, 1), dtype=np.uint8)
    space = gym.spaces.Dict({"pixels": frames, "state": make_env("CartPole-v1").observation_space})
    model = make_reward_model(space, gym.spaces.Discrete(2), hidden_sizes=[8], observation_keys=["pixels"], frame_stack=2,
                              pixels={"size": [36, 36], "grayscale": True}, cnn={"channels": [4], "kernels": [8], "strides": [4], "features": 16})
    run = save_reward_run(model, tmp_path / "pixel-reward", env_id="CartPole-v1", source="test: a pixel reward")
    result = run_cli("eval", "reward", str(run), "--env", "CartPole-v1")
    assert result.returncode == 1 and result.stderr.count("\n") == 1 and "Traceback" not in result.stderr, result.stderr
    assert f"{run}: eval reward does not support rewards of image or Dict observations yet (this one reads Dict(pixels: Box(uint8, (2, 36, 36, 1))" in result.stderr
    assert not (run / "eval-reward").exists() and not (run / "eval-reward.partial").exists()
