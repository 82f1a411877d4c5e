"""`train irl` (tabular maxent/mce, continuous gcl, airl and gail) from the command line, feeding `train ppo --reward`."""

from __future__ import annotations

import json

import pytest
from support import DATASETS, run_cli, run_cli_many
from test_cli import assert_one_line_error, last_json

from imitation.errors import ImitationError

GRID = "imitation/GridWorld8x8Slippery-v0"


@pytest.fixture(scope="module")
def grid_demos(tmp_path_factory):
    path = tmp_path_factory.mktemp("grid") / "slippery.mcap"
    last_json(run_cli("record", "--env", GRID, "--expert", "scripted", "--episodes", "50", "--out", str(path), "--json"))
    return path


@pytest.fixture(scope="module")
def mce_run(grid_demos, tmp_path_factory):
    out = tmp_path_factory.mktemp("irl") / "mce"
    return out, last_json(run_cli("train", "irl", "--method", "mce", "--env", GRID, "--demos", str(grid_demos), "--iterations", "300", "--out", str(out), "--json"))


def test_mce_irl_recovers_a_reward_worth_nine_tenths_of_the_expert(mce_run) -> None:
    out, result = mce_run
    assert result["method"] == "mce" and result["demo_episodes"] == 50 and result["iterations"] == 300
    assert result["normalized_return"] >= 0.9
    assert {"config.json", "model.safetensors", "metrics.json", "progress.csv", "irl_curve.png", "reward_maps.png", "occupancy_maps.png"} <= {p.name for p in out.iterdir()}
    config = json.loads((out / "config.json").read_text())
    assert config["kind"] == "reward" and config["reward"]["state_features"] == 3
    rows = (out / "progress.csv").read_text().splitlines()
    assert rows[0].startswith("iteration,loss,occupancy_error") and len(rows) == 301


def test_ppo_optimises_the_recovered_tabular_reward(mce_run, tmp_path) -> None:
    out, _ = mce_run
    result = last_json(run_cli("train", "ppo", "--env", GRID, "--reward", str(out), "--steps", "2048", "--out", str(tmp_path / "ppo"), "--json", timeout=300))
    assert result["steps"] >= 2048 and "mean_return" in result["eval"]


def test_gcl_writes_a_reward_model_that_ppo_consumes(tmp_path) -> None:
    env_id, demos = "imitation/CartPoleFixedHorizon-v0", str(DATASETS / "CartPoleFixedHorizon-v0.mcap")
    gcl = tmp_path / "gcl"
    result = last_json(run_cli("train", "irl", "--method", "gcl", "--env", env_id, "--demos", demos, "--steps", "2048", "--out", str(gcl), "--json", timeout=300))
    assert result["method"] == "gcl" and result["steps"] == 2048 and result["demo_return"] == 500.0
    assert 0.0 <= result["demo_accuracy"] <= 1.0 and "mean_return" in result["eval"]
    config = json.loads((gcl / "config.json").read_text())
    assert config["kind"] == "reward" and config["reward"]["normalize_observations"] and "policy" in config
    assert {"learning_curve.png", "reward_curve.png"} <= {p.name for p in gcl.iterdir()}
    last_json(run_cli("train", "ppo", "--env", env_id, "--reward", str(gcl), "--steps", "2048", "--out", str(tmp_path / "ppo"), "--json", timeout=300))
    last_json(run_cli("eval", "policy", str(gcl), "--env", env_id, "--episodes", "1", "--json"))


@pytest.mark.parametrize("variant", ["airl", "gail", "gail-logit"])
def test_adversarial_runs_write_a_policy_and_a_reward_that_ppo_and_eval_consume(variant: str, tmp_path) -> None:
    env_id, demos = "imitation/CartPoleFixedHorizon-v0", str(DATASETS / "CartPoleFixedHorizon-v0.mcap")
    method, run = variant.split("-")[0], tmp_path / variant
    flags = ["--discriminator-steps", "2", "--policy-updates", "2", "--pool-rollouts", "3", "--latest-share", "0.5", "--gradient-penalty", "0.5", "--hidden", "16"]
    flags += ["--gail-reward", "logit"] if variant == "gail-logit" else []
    result = last_json(run_cli("train", "irl", "--method", method, "--env", env_id, "--demos", demos, "--steps", "2048", *flags, "--out", str(run), "--json", timeout=300))
    assert result["method"] == method and result["steps"] == 2048 and result["demo_return"] == 500.0
    assert 0.0 <= result["demo_accuracy"] <= 1.0 and 0.0 <= result["sample_accuracy"] <= 1.0
    config = json.loads((run / "config.json").read_text())
    assert config["irl"] | {"method": method, "discriminator_steps": 2, "policy_updates": 2, "pool_rollouts": 3, "latest_share": 0.5, "gradient_penalty": 0.5, "hidden_sizes": [16]} == config["irl"]
    # AIRL exports g, a reward of the state alone; GAIL its discriminator's −log(1 − D), or its logit, of (s, a).
    assert config["reward"]["inputs"] == {"airl": "s", "gail": "sa"}[method]
    assert config["reward"]["output"] == {"airl": "linear", "gail": "softplus", "gail-logit": "linear"}[variant]
    assert config["irl"]["gail_reward"] == ("logit" if variant == "gail-logit" else "softplus")
    rows = (run / "progress.csv").read_text().splitlines()
    assert "discriminator_loss" in rows[0] and len(rows) == 1 + 2048 // 256
    assert {"learning_curve.png", "reward_curve.png"} <= {p.name for p in run.iterdir()}
    last_json(run_cli("train", "ppo", "--env", env_id, "--reward", str(run), "--steps", "2048", "--out", str(tmp_path / "ppo"), "--json", timeout=300))
    # AIRL also saves its potential h, for PPO on f = g + γh(s') − h(s); GAIL has none to shape with.
    shaped = run_cli("train", "ppo", "--env", env_id, "--reward", str(run), "--shaped", "--steps", "2048", "--out", str(tmp_path / "shaped"), "--json", timeout=300)
    if method == "airl":
        assert config["potential"]["inputs"] == "s"
        last_json(shaped)
        assert json.loads((tmp_path / "shaped" / "config.json").read_text())["source"] == f"--reward {run} --shaped"
    else:
        assert "potential" not in config
        assert_one_line_error(shaped, "holds no shaping potential h")
        assert not (tmp_path / "shaped").exists()
    evaluation = last_json(run_cli("eval", "policy", str(run), "--env", env_id, "--episodes", "2", "--json"))
    assert evaluation["episodes"] == 2 and "mean_return" in evaluation
    judged = last_json(run_cli("eval", "reward", str(run), "--env", env_id, "--retrain-steps", "0", "--quiet", "--json", "--out", str(tmp_path / "judged"), timeout=300))
    assert 0.0 <= judged["epic"] <= 1.0 and set(judged["controls"]) == {"constant", "random"}


@pytest.mark.parametrize("method", ["gcl", "mce"])
@pytest.mark.parametrize("flag", ["--discriminator-steps", "--policy-updates", "--pool-rollouts", "--latest-share", "--gradient-penalty"])
def test_discriminator_flags_are_refused_by_a_method_without_a_discriminator(method: str, flag: str, tmp_path) -> None:
    from cli import make_parser

    args = make_parser().parse_args(
        ["train", "irl", "--method", method, "--env", "CartPole-v1", "--demos", "d.mcap", flag, "2", "--out", str(tmp_path / "r")]
    )
    with pytest.raises(ImitationError, match=f"^{flag}: sets the training of GAIL's and AIRL's discriminator, and --method {method} has none$"):
        args.handler(args)
    assert not any(tmp_path.iterdir())


def test_bad_irl_input(grid_demos, tmp_path) -> None:
    cartpole = str(DATASETS / "CartPole-v1.mcap")
    assert_one_line_error(run_cli("train", "irl", "--env", GRID, "--demos", cartpole, "--out", str(tmp_path / "a")), "CartPole-v1.mcap")
    assert_one_line_error(run_cli("train", "irl", "--method", "mce", "--env", "CartPole-v1", "--demos", cartpole, "--out", str(tmp_path / "b")), "not a tabular MDP")
    assert_one_line_error(run_cli("train", "irl", "--method", "maxent", "--env", GRID, "--demos", str(grid_demos), "--out", str(tmp_path / "c")), "deterministic dynamics")
    assert_one_line_error(run_cli("train", "irl", "--method", "gcl", "--env", GRID, "--demos", cartpole, "--out", str(tmp_path / "d")), "CartPole-v1.mcap")
    assert not any(tmp_path.iterdir())


def test_a_reward_model_of_another_env_is_refused(mce_run, tmp_path) -> None:
    out, _ = mce_run
    assert_one_line_error(run_cli("train", "ppo", "--env", "CartPole-v1", "--reward", str(out), "--steps", "2048", "--out", str(tmp_path / "p")), "reward model")


def test_gcl_on_pixel_demos_learns_a_cnn_reward_that_ppo_on_the_same_frames_optimises(tmp_path) -> None:
    import torch

    from imitation.algorithms.gcl import GCLConfig
    from imitation.algorithms.ppo import PPOConfig
    from imitation.jobs.irl import gcl_job
    from imitation.rewards import load_reward

    env_id, demos = "CartPole-v1", tmp_path / "pixels.mcap"  # not fixed-horizon: its final evaluations render 10 short episodes
    last_json(run_cli("record", "--env", env_id, "--expert", "scripted", "--episodes", "1", "--pixels", "36x36", "--grayscale", "--frame-stack", "2", "--out", str(demos), "--json"))
    ppo = PPOConfig(env_id=env_id, n_envs=2, n_steps=16, batch_size=16, n_epochs=1, total_steps=32, normalize_rewards=True,
                    cnn={"channels": [4], "kernels": [8], "strides": [4], "features": 16})
    result = gcl_job([str(demos)], env_id, GCLConfig(hidden_sizes=[8], warmup_steps=2, reward_steps=1, batch_size=16), ppo, tmp_path / "gcl", progress=False)
    assert result["steps"] == 32 and 0.0 <= result["demo_accuracy"] <= 1.0
    reward = load_reward(tmp_path / "gcl")
    assert reward.config.pixels == {"size": [36, 36], "grayscale": True} and reward.config.frame_stack == 2 and len(reward.encoders) == 1
    frames = {"pixels": torch.randint(0, 256, (5, 2, 36, 36, 1), dtype=torch.uint8), "state": torch.zeros(5, 4)}
    rewards = reward(frames, torch.zeros(5), frames)
    assert rewards.shape == (5,) and rewards.std() > 0, "the reward reads the frames"
    # train ppo --reward takes the frames, stack and keys the reward reads from its run: flags that agree pass (up to
    # PPOConfig's own check of --steps, here too few), flags that disagree are refused naming both values.
    gcl = str(tmp_path / "gcl")
    on_reward = ["train", "ppo", "--env", env_id, "--reward", gcl, "--n-envs", "1"]
    evaluated, gcl_preset, adopted, agreeing, other_stack, other_frames = run_cli_many([
        ["eval", "policy", gcl, "--env", env_id, "--episodes", "1", "--json"],
        ["train", "irl", "--method", "gcl", "--env", env_id, "--demos", str(demos), "--steps", "10", "--out", str(tmp_path / "g2")],
        [*on_reward, "--steps", "128", "--out", str(tmp_path / "ppo"), "--json"],
        [*on_reward, "--pixels", "36x36", "--grayscale", "--frame-stack", "2", "--steps", "10", "--out", str(tmp_path / "p2")],
        [*on_reward, "--frame-stack", "3", "--out", str(tmp_path / "p3")],
        [*on_reward, "--pixels", "48x48", "--out", str(tmp_path / "p4")],
    ])
    last_json(evaluated)
    assert_one_line_error(gcl_preset, "less than one rollout (8 envs × 128 steps)")  # the pixel preset, chosen by the demos' frames
    assert last_json(adopted)["steps"] == 128
    config = json.loads((tmp_path / "ppo" / "config.json").read_text())
    assert config["ppo"]["pixels"] == reward.config.pixels and config["ppo"]["frame_stack"] == 2 and config["ppo"]["observation_keys"] == ["pixels"]
    assert config["ppo"]["n_epochs"] == 4 and config["ppo"]["clip_range"] == 0.1, "the pixel preset"
    assert_one_line_error(agreeing, "less than one rollout")
    assert_one_line_error(other_stack, f"--frame-stack 3 disagrees with the reward model of {gcl}, learnt on --frame-stack 2: leave the flag out")
    assert_one_line_error(other_frames, f"--pixels 48x48 disagrees with the reward model of {gcl}, learnt on --pixels 36x36 --grayscale")


def _adversarial_run(out, method: str, *, warm_start=None, learning_rate: float = 3e-4, hidden: int = 16, seed: int = 1) -> dict:
    from imitation.algorithms.adversarial import AdversarialConfig
    from imitation.jobs.irl import adversarial_job
    from imitation.jobs.presets import ppo_config

    env_id = "imitation/CartPoleFixedHorizon-v0"
    config = AdversarialConfig(method=method, hidden_sizes=[hidden], potential_hidden_sizes=[hidden], learning_rate=learning_rate, discriminator_steps=2, seed=seed)
    ppo = ppo_config(env_id, beside_irl=True, total_steps=512, seed=seed)
    demos = [str(DATASETS / "CartPoleFixedHorizon-v0.mcap")]
    return adversarial_job(demos, env_id, config, ppo, out, progress=False, warm_start=warm_start)


@pytest.mark.parametrize("method", ["airl", "gail"])
def test_warm_start_gives_the_discriminator_a_finished_runs_networks_and_their_statistics(method: str, tmp_path) -> None:
    import torch

    from imitation.rewards import load_potential, load_reward

    first = _adversarial_run(tmp_path / "first", method)["run"]
    # An Adam step of 1e-30 leaves float32 weights as they were: these runs save what they started
    # from. Another seed's first rollout would give other observation statistics.
    still = _adversarial_run(tmp_path / "still", method, warm_start=first, learning_rate=1e-30, seed=2)["run"]
    fresh = _adversarial_run(tmp_path / "fresh", method, learning_rate=1e-30, seed=2)["run"]
    loads = [load_reward, *([load_potential] if method == "airl" else [])]
    for load in loads:
        started, saved, unstarted = (load(run).state_dict() for run in (still, first, fresh))
        assert all(torch.equal(started[name], saved[name]) for name in saved)
        assert not torch.equal(unstarted["observation_std"], saved["observation_std"])
        assert not torch.equal(unstarted["net.0.weight"], saved["net.0.weight"])
    assert json.loads((tmp_path / "still" / "config.json").read_text())["irl"]["warm_start"] == str(first)
    assert "warm_start" not in json.loads((tmp_path / "first" / "config.json").read_text())["irl"]


def test_warm_start_refuses_another_method_or_other_networks(tmp_path) -> None:
    first = _adversarial_run(tmp_path / "first", "airl")["run"]
    with pytest.raises(ImitationError, match=r"first: --warm-start needs a finished `train irl --method gail` run, not a 'airl' one$"):
        _adversarial_run(tmp_path / "gail", "gail", warm_start=first)
    with pytest.raises(ImitationError, match=r"first: --warm-start: its g network's hidden_sizes is \[16\], this run's \[8\]$"):
        _adversarial_run(tmp_path / "narrow", "airl", warm_start=first, hidden=8)
    with pytest.raises(ImitationError, match="not a run directory"):
        _adversarial_run(tmp_path / "none", "airl", warm_start=tmp_path / "missing")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["first"]


def test_warm_start_is_refused_by_a_method_without_a_discriminator(tmp_path) -> None:
    from cli import make_parser

    args = make_parser().parse_args(
        ["train", "irl", "--method", "gcl", "--env", "CartPole-v1", "--demos", "d.mcap", "--warm-start", "r", "--out", str(tmp_path / "r")]
    )
    with pytest.raises(ImitationError, match="^--warm-start: starts GAIL's and AIRL's discriminator, and --method gcl has none$"):
        args.handler(args)
