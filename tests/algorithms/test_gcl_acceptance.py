"""Issue 5's continuous acceptance: GCL on bundled demos, PPO from scratch on the recovered reward,
the true return normalised between a random policy (0) and the demos (1). Slow (minutes a seed).

The steps are those `train irl --method gcl` and `eval reward` default to. Measured 2026-11-22
(seeds 0, 1, 2): CartPoleFixedHorizon (GCL 200k, retraining 300k) 1.00, 1.00, 1.00, a constant
reward 0.02; Pendulum (GCL 500k, retraining 600k) 1.04, 1.05, 1.05. Again at the README's
commands on 2026-12-07: CartPole 1.00, 1.00, 1.00; Pendulum 1.05, 0.67, 1.05. Before PPO inside GCL
optimised r_θ - log π_k (the maximum-entropy policy the discriminator assumes), Pendulum gave
1.02, 0.89, 0.74: the discriminator told demos from samples by log π_k alone and r_θ stayed flat."""

from __future__ import annotations

import numpy as np
import pytest
from support import DATASETS, random_policy_return

from imitation.algorithms.gcl import GCLConfig
from imitation.algorithms.ppo import PPOConfig
from imitation.envs.make import make_env
from imitation.jobs.irl import gcl_job
from imitation.jobs.ppo import ppo_job
from imitation.jobs.presets import ppo_settings, preset
from imitation.rewards import make_reward_model, reward_tensors
from imitation.runs import RunWriter


def _pipeline(env_id: str, demos: str, seed: int, tmp_path, *, irl_steps: int, retrain_steps: int, reward_run=None) -> float:
    """The true mean return of PPO trained from scratch on the recovered (or given) reward."""
    if reward_run is None:
        reward_run = tmp_path / f"gcl-{seed}"
        gcl_job([demos], env_id, GCLConfig(seed=seed), PPOConfig(env_id=env_id, total_steps=irl_steps, seed=seed, **ppo_settings(env_id, beside_irl=True)), reward_run, progress=False)
    retrained = ppo_job(
        PPOConfig(env_id=env_id, total_steps=retrain_steps, seed=seed, **ppo_settings(env_id, learned_reward=True)),
        tmp_path / f"ppo-{seed}", reward_run=str(reward_run), progress=False,
    )
    return retrained["eval"]["mean_return"]


def _constant_reward_run(env_id: str, path) -> str:
    env = make_env(env_id)
    model = make_reward_model(env.observation_space, env.action_space, hidden_sizes=[])
    for parameter in model.parameters():
        parameter.data.zero_()
    with RunWriter(path, config={"kind": "reward", "env_id": env_id, "reward": model.config.to_json()}, tensorboard=False) as run:
        run.save_weights(reward_tensors(model))
        run.finish({})
    return str(path)


@pytest.mark.slow
def test_gcl_on_fixed_horizon_cartpole_retrains_to_nine_tenths_and_beats_a_constant_reward(tmp_path) -> None:
    env_id, demos = "imitation/CartPoleFixedHorizon-v0", str(DATASETS / "CartPoleFixedHorizon-v0.mcap")
    expert, random = 500.0, random_policy_return(env_id)
    steps = {"irl_steps": preset(env_id).irl_steps, "retrain_steps": preset(env_id).retrain_steps}
    learned = [(_pipeline(env_id, demos, seed, tmp_path, **steps) - random) / (expert - random) for seed in (0, 1, 2)]
    constant = (_pipeline(env_id, demos, 0, tmp_path, irl_steps=0, retrain_steps=steps["retrain_steps"], reward_run=_constant_reward_run(env_id, tmp_path / "constant")) - random) / (expert - random)
    print(f"fixed-horizon CartPole, retrained on GCL's reward, normalised: {learned}; constant reward: {constant}")
    assert min(learned) >= 0.9 and np.mean(learned) > constant + 0.5, (learned, constant)


@pytest.mark.slow
def test_gcl_on_pendulum_retrains_to_the_demos_return_on_two_seeds_of_three(tmp_path) -> None:
    """The README's claim. Measured 2026-12-07 (seeds 0, 1, 2): 1.05, 0.67, 1.05; PPO on Pendulum's
    own reward reaches −147, −430, −147 at 200k steps, seed 1 the poor one there too."""
    env_id, demos = "Pendulum-v1", str(DATASETS / "Pendulum-v1.mcap")
    expert, random = -160.2, random_policy_return(env_id)
    steps = {"irl_steps": preset(env_id).irl_steps, "retrain_steps": preset(env_id).retrain_steps}
    learned = [(_pipeline(env_id, demos, seed, tmp_path, **steps) - random) / (expert - random) for seed in (0, 1, 2)]
    print(f"Pendulum, retrained on GCL's reward, normalised: {learned}")
    assert sorted(learned)[1] >= 0.95 and min(learned) >= 0.5, learned
