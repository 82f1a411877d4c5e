"""`train irl --method apprenticeship` from the command line: the run directory it writes, which
`eval policy`, `eval reward` and `train ppo --reward` accept, and the acceptance figures of issue 18
(the CartPole one marked slow)."""

from __future__ import annotations

import json

import pytest
from support import DATASETS, run_cli_many
from test_cli import last_json

from imitation.runs import read_run

GRIDS = ["imitation/GridWorld8x8-v0", "imitation/GridWorld8x8Slippery-v0"]
CARTPOLE = "imitation/CartPoleFixedHorizon-v0"


def _apprenticeship(env_id: str, demos: str, out, *flags: str) -> list[str]:
    return [
        "train",
        "irl",
        "--method",
        "apprenticeship",
        "--env",
        env_id,
        "--demos",
        demos,
        *flags,
        "--quiet",
        "--out",
        str(out),
        "--json",
    ]


def test_tabular_runs_match_the_experts_and_other_commands_accept_them(tmp_path) -> None:
    """Issue 18 on both bundled gridworlds: ‖μ̄ - μ_E‖₂ ≤ 0.05 ‖μ_E‖₂ and the mixture's exact
    return normalised ≥ 0.9; then `eval policy` and `eval reward` on a run."""
    runs = [tmp_path / env_id.split("/")[1] for env_id in GRIDS]
    deterministic, slippery, policy, reward = run_cli_many(
        [
            *[
                _apprenticeship(env_id, str(DATASETS / f"{run.name}.mcap"), run)
                for env_id, run in zip(GRIDS, runs, strict=True)
            ],
            ["eval", "policy", str(runs[0]), "--env", GRIDS[0], "--episodes", "3", "--json"],
            [
                "eval",
                "reward",
                str(runs[0]),
                "--env",
                GRIDS[0],
                "--retrain-steps",
                "0",
                "--quiet",
                "--out",
                str(tmp_path / "eval"),
                "--json",
            ],
        ]
    )
    for run, result in zip(runs, [last_json(deterministic), last_json(slippery)], strict=True):
        assert result["method"] == "apprenticeship" and result["demo_episodes"] == 50 and result["converged"]
        assert result["relative_feature_distance"] <= 0.05
        assert result["mixture"]["normalized_return"] >= 0.9
        lambdas = result["mixture"]["lambdas"]
        assert len(lambdas) == result["iterations"] + 1 and abs(sum(lambdas) - 1.0) < 1e-12
        assert {"config.json", "model.safetensors", "metrics.json", "progress.csv", "irl_curve.png", "reward_maps.png"} <= {
            p.name for p in run.iterdir()
        }
        config, weights = read_run(run)
        assert (
            config["kind"] == "reward"
            and config["irl"]["method"] == "apprenticeship"
            and config["reward"]["state_features"] == 3
        )
        assert config["policy"]["hidden_sizes"] == [] and weights["mixture.lambdas"].tolist() == lambdas
        assert weights["reward.net.0.weight"].flatten().tolist() == pytest.approx(result["reward_weights"])
        # The reward the run keeps pays the goal and charges lava, like the true one (0, -2, 2).
        floor, lava, goal = result["reward_weights"]
        assert goal > floor > lava
    # Deterministic dynamics: the network plays the member's first-step decisions, whose exact return metrics.json gives.
    metrics = json.loads((runs[0] / "metrics.json").read_text())
    assert last_json(policy)["mean_return"] == pytest.approx(metrics["policy"]["stationary_return"])
    assert "epic" in last_json(reward)


def test_cartpole_run_holds_the_reward_the_mixture_and_a_policy(tmp_path) -> None:
    """The PPO version's mechanics, in seconds: one iteration of 256 PPO steps, μ from 2 episodes;
    `eval policy` and `train ppo --reward` on the run."""
    run = tmp_path / "cartpole"
    flags = ["--iterations", "1", "--steps", "256", "--episodes", "2"]
    trained, policy, ppo = run_cli_many(
        [
            _apprenticeship(CARTPOLE, str(DATASETS / "CartPoleFixedHorizon-v0.mcap"), run, *flags),
            ["eval", "policy", str(run), "--env", CARTPOLE, "--episodes", "1", "--json"],
            [
                "train",
                "ppo",
                "--env",
                CARTPOLE,
                "--reward",
                str(run),
                "--steps",
                "256",
                "--quiet",
                "--out",
                str(tmp_path / "ppo"),
                "--json",
            ],
        ]
    )
    result = last_json(trained)
    assert result["iterations"] == 1 and result["steps"] == 256 and len(result["mixture"]["lambdas"]) == 2
    assert len(result["reward_weights"]) == 3 and "mean_return" in result["eval"]
    config, weights = read_run(run)
    assert config["reward"]["hidden_sizes"] == [6] and config["ppo"]["total_steps"] == 256 and config["irl"]["episodes"] == 2
    assert {"mixture.policy0.action_head.weight", "mixture.policy1.action_head.weight", "policy.action_head.weight"} <= set(
        weights
    )
    assert last_json(policy)["episodes"] == 1 and last_json(ppo)["steps"] >= 256


@pytest.mark.slow
def test_ppo_retrained_on_the_recovered_cartpole_reward_earns_nine_tenths_of_the_demos(tmp_path) -> None:
    """Issue 18: PPO retrained from scratch (`train ppo --reward`, 300,000 steps) on the reward of
    two iterations of 100,000 PPO steps earns ≥ 0.9 of the demos' return, normalised by `eval policy`."""
    run, ppo = tmp_path / "cartpole", tmp_path / "ppo"
    trained, retrained, evaluation = run_cli_many(
        [
            _apprenticeship(
                CARTPOLE, str(DATASETS / "CartPoleFixedHorizon-v0.mcap"), run, "--iterations", "2", "--steps", "100000"
            ),
            [
                "train",
                "ppo",
                "--env",
                CARTPOLE,
                "--reward",
                str(run),
                "--steps",
                "300000",
                "--quiet",
                "--out",
                str(ppo),
                "--json",
            ],
            ["eval", "policy", str(ppo), "--env", CARTPOLE, "--json"],
        ],
        timeout=7200,
    )
    assert last_json(trained)["steps"] >= 200_000 and last_json(retrained)["steps"] >= 300_000
    assert last_json(evaluation)["normalized_return"] >= 0.9
