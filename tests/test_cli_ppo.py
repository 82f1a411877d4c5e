"""`train ppo`, `eval policy` and `record --expert RUN_DIR` from the command line, and their errors."""

from __future__ import annotations

import dataclasses
import json

import gymnasium as gym
import numpy as np
import pytest
import torch
from support import DATASETS, run_cli, run_cli_many
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


# -- pixels: a CNN policy on CartPole's rendered frames ------------------------------------------

PIXEL_FLAGS = ("--pixels", "36x36", "--grayscale", "--frame-stack", "2", "--n-envs", "1")  # one rollout: the preset's 128 steps


@pytest.fixture(scope="module")
def pixel_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("pixels") / "cartpole"
    args = ("train", "ppo", "--env", "CartPole-v1", *PIXEL_FLAGS, "--steps", "128", "--seed", "1", "--quiet", "--out", str(out), "--json")
    return out, last_json(run_cli(*args, timeout=300))


def test_train_ppo_on_pixels_saves_a_cnn_policy_that_eval_rebuilds_its_env_for(pixel_run) -> None:
    out, result = pixel_run
    assert result["steps"] == 128 and result["eval"]["episodes"] == 10
    config = json.loads((out / "config.json").read_text())
    assert config["ppo"]["pixels"] == {"size": [36, 36], "grayscale": True} and config["ppo"]["frame_stack"] == 2
    policy = config["policy"]
    assert policy["observation_keys"] == ["pixels"] and policy["frame_stack"] == 2 and policy["pixels"] == config["ppo"]["pixels"]
    assert policy["observation_space"]["spaces"]["pixels"]["shape"] == [2, 36, 36, 1]
    evaluated = last_json(run_cli("eval", "policy", str(out), "--env", "CartPole-v1", "--episodes", "2", "--json"))
    assert evaluated["episodes"] == 2 and evaluated["mean_return"] >= 8


def test_a_pixel_rollout_keeps_frames_as_uint8_and_the_update_trains_the_cnn() -> None:
    from imitation.algorithms.ppo import PPO, PPOConfig

    config = PPOConfig(env_id="CartPole-v1", pixels={"size": [36, 36], "grayscale": True}, frame_stack=2, n_envs=2, n_steps=8,
                       batch_size=8, n_epochs=1, total_steps=16, cnn={"channels": [4], "kernels": [8], "strides": [4], "features": 16})
    learner = PPO(config)
    try:
        rollout = learner.collect_rollout()
        frames, state = rollout.observations["pixels"], rollout.observations["state"]
        assert frames.dtype == torch.uint8 and frames.shape == (8, 2, 2, 36, 36, 1) and frames.float().std() > 0
        assert rollout.next_observations["pixels"].dtype == torch.uint8 and state.dtype == torch.float32
        assert learner.buffers.features is None, "an image policy keeps no fixed features: its CNN is trained"
        before = learner.policy.image_encoders[0].convolutions[0].weight.detach().clone()
        learner.update(rollout, rollout.env_rewards)
        assert not torch.equal(before, learner.policy.image_encoders[0].convolutions[0].weight)
    finally:
        learner.close()


def test_a_pixel_checkpoint_resumes_the_same_policy() -> None:
    from imitation.algorithms.ppo import PPO, PPOConfig

    config = PPOConfig(env_id="CartPole-v1", pixels={"size": [36, 36], "grayscale": True}, frame_stack=2, n_envs=2, n_steps=8,
                       batch_size=8, n_epochs=1, total_steps=32, normalize_observations=True,
                       cnn={"channels": [4], "kernels": [8], "strides": [4], "features": 16})
    learner, resumed = PPO(config), PPO(config)
    try:
        learner.step()
        tensors, state = learner.state_dict()
        resumed.load_state_dict(({name: t.clone() for name, t in tensors.items()}, json.loads(json.dumps(state))))
        for name, tensor in learner.policy.state_dict().items():
            assert torch.equal(tensor, resumed.policy.state_dict()[name]), name
        assert resumed.updates == 1 and resumed.policy.pixel_statistics[0].count > 100
        frames = {"pixels": torch.randint(0, 256, (3, 2, 36, 36, 1), dtype=torch.uint8), "state": torch.zeros(3, 4)}
        assert torch.equal(learner.policy.value(learner.policy.encode(frames)), resumed.policy.value(resumed.policy.encode(frames)))
    finally:
        learner.close()
        resumed.close()


def test_frame_stack_needs_image_observations(tmp_path) -> None:
    assert_one_line_error(run_cli("train", "ppo", "--env", "CartPole-v1", "--frame-stack", "4", "--out", str(tmp_path / "r")), "frame stacking needs image observations")


class _Frames(gym.Env):
    """An env that observes images itself (no --pixels), for the preset's choice; never stepped."""

    observation_space = gym.spaces.Box(0, 255, (8, 8, 1), dtype=np.uint8)
    action_space = gym.spaces.Discrete(2)


def test_image_observations_get_the_zoo_atari_preset_that_flags_override() -> None:
    from imitation.jobs.presets import ppo_config

    pixels = {"size": [36, 36], "grayscale": True}
    gym.register("test/Frames-v0", entry_point=_Frames)
    vector, rendered, native = ppo_config("CartPole-v1"), ppo_config("CartPole-v1", pixels=pixels), ppo_config("test/Frames-v0")
    assert (vector.n_epochs, vector.clip_range, vector.gamma) == (20, 0.2, 0.98), "CartPole's vector-state preset"
    for images in (rendered, native):
        settings = (images.n_envs, images.n_steps, images.n_epochs, images.batch_size, images.learning_rate, images.anneal_lr)
        assert settings == (8, 128, 4, 256, 2.5e-4, True)
        assert (images.clip_range, images.entropy_coef, images.value_coef, images.gamma, images.gae_lambda) == (0.1, 0.01, 0.5, 0.99, 0.95)
    overridden = ppo_config("CartPole-v1", pixels=pixels, n_envs=2, total_steps=512)
    assert (overridden.n_envs, overridden.n_epochs, overridden.total_steps) == (2, 4, 512)


def test_halfcheetah_gets_the_zoo_preset_but_beside_a_reward_being_learnt() -> None:
    """`train ppo` on fixed-horizon HalfCheetah's own reward, or on a learned one (`train ppo --reward`,
    `eval reward`'s retraining), gets rl-baselines3-zoo's tuned PPO, with rewards normalised; the policy
    `train irl` trains beside its discriminator keeps the continuous-control settings, as Hopper has
    everywhere."""
    from imitation.jobs.irl_methods import IRLRun, ppo_beside_irl
    from imitation.jobs.presets import ppo_config, ppo_settings

    env_id = "imitation/HalfCheetahFixedHorizon-v0"
    ppo, learned, beside = ppo_config(env_id), ppo_config(env_id, learned_reward=True), ppo_config(env_id, beside_irl=True)
    for zoo in (ppo, learned):
        assert (zoo.n_steps, zoo.n_epochs, zoo.gamma, zoo.gae_lambda, zoo.clip_range, zoo.anneal_lr) == (512, 20, 0.98, 0.92, 0.1, False)
        assert (zoo.hidden_sizes, zoo.activation, zoo.log_std_init, zoo.learning_rate) == ([256, 256], "relu", -2.0, 2.0633e-05)
    assert learned.normalize_rewards and beside.normalize_rewards
    assert ppo_settings("CartPole-v1", beside_irl=True)["normalize_rewards"] and "normalize_rewards" not in ppo_settings("CartPole-v1")
    run = IRLRun("airl", [str(DATASETS / "Pendulum-v1.mcap")], env_id, "r", {})  # `train irl` with no flags
    assert ppo_beside_irl(run) == dataclasses.replace(beside, total_steps=3_000_000), "`train irl`'s policy"
    for continuous in (beside, ppo_config("imitation/HopperFixedHorizon-v0", learned_reward=True)):
        assert (continuous.n_steps, continuous.n_epochs, continuous.gamma, continuous.hidden_sizes) == (2048, 10, 0.99, [64, 64])
        assert (continuous.activation, continuous.log_std_init, continuous.learning_rate) == ("tanh", 0.0, 3e-4)


def test_resume_takes_the_interrupted_runs_frames_and_refuses_flags_that_disagree(tmp_path) -> None:
    from imitation.algorithms.ppo import PPO
    from imitation.jobs.presets import ppo_config
    from imitation.jobs.run_config import RunConfig, config_json

    # Stopped after the first of its two updates, as Ctrl-C leaves `train ppo --env CartPole-v1 --pixels 36x36
    # --grayscale --frame-stack 2 --n-envs 1 --steps 256`.
    out = tmp_path / "ppo"
    config = ppo_config("CartPole-v1", pixels={"size": [36, 36], "grayscale": True}, frame_stack=2, n_envs=1, total_steps=256)
    learner = PPO(config)
    try:
        learner.step()
        tensors, state = learner.state_dict()
    finally:
        learner.close()
    run_config = RunConfig(kind="ppo", env_id="CartPole-v1", ppo=config_json(config)).to_json()
    with pytest.raises(KeyboardInterrupt), RunWriter(out, config=run_config, tensorboard=False) as run:
        run.save_checkpoint(tensors, state)
        raise KeyboardInterrupt
    args = ["train", "ppo", "--env", "CartPole-v1", "--n-envs", "1", "--steps", "256", "--quiet", "--out", str(out), "--resume"]
    other, resumed = run_cli_many([[*args, "--frame-stack", "3"], [*args, "--json"]])
    assert_one_line_error(other, f"--frame-stack 3 disagrees with the interrupted run in {out}.partial, started with --frame-stack 2")
    assert last_json(resumed)["steps"] == 256
    policy = json.loads((out / "config.json").read_text())["policy"]
    assert policy["pixels"] == config.pixels and policy["frame_stack"] == 2
