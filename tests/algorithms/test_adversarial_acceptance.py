"""Issue 20's CartPole acceptance: AIRL on the bundled fixed-horizon demos, then PPO from scratch on
its recovered reward g, the true return normalised between a random policy (0) and the demos (1).
The slow test runs the steps `train irl` and `eval reward` default to (minutes); the fast one a short
AIRL run whose g must already rank the demos' states above failing and tilting."""

from __future__ import annotations

import pytest
import torch
from support import DATASETS, random_policy_return

from imitation.algorithms.adversarial import AdversarialConfig
from imitation.algorithms.ppo import PPOConfig
from imitation.data.dataset import DemoDataset
from imitation.data.loader import load_transitions, transitions_to_torch
from imitation.jobs.irl import adversarial_job
from imitation.jobs.ppo import ppo_job
from imitation.jobs.presets import ppo_settings, preset
from imitation.rewards import load_reward

ENV_ID = "imitation/CartPoleFixedHorizon-v0"
DEMOS = str(DATASETS / "CartPoleFixedHorizon-v0.mcap")


def _airl(tmp_path, seed: int, steps: int) -> str:
    run = tmp_path / f"airl-{seed}"
    config = PPOConfig(env_id=ENV_ID, total_steps=steps, seed=seed, **ppo_settings(ENV_ID, beside_irl=True))
    adversarial_job([DEMOS], ENV_ID, AdversarialConfig(method="airl", seed=seed), config, run, progress=False)
    return str(run)


def test_a_short_airl_run_rates_the_demos_states_above_failing_and_tilting(tmp_path) -> None:
    g = load_reward(_airl(tmp_path, 0, 30_000))
    demos = transitions_to_torch(load_transitions(DemoDataset([DEMOS]), next_observations=True))
    observations = demos.observations[:1000]
    assert isinstance(observations, torch.Tensor)
    failed, tilted = observations.clone(), observations.clone()
    failed[:, 4] = 1.0  # the absorbing state's flag
    tilted[:, 2] = 0.15  # 8.6°, most of the way to CartPole's 12° limit

    def mean_g(states: torch.Tensor) -> float:
        return g.rewards_of(states, demos.actions[:1000], states).mean().item()

    assert mean_g(observations) > mean_g(tilted) + 0.25 and mean_g(observations) > mean_g(failed) + 2.0


@pytest.mark.slow
def test_airls_recovered_reward_retrains_ppo_to_nine_tenths_on_fixed_horizon_cartpole(tmp_path) -> None:
    reward = _airl(tmp_path, 0, 100_000)
    config = PPOConfig(env_id=ENV_ID, total_steps=preset(ENV_ID).retrain_steps, seed=0, **ppo_settings(ENV_ID, learned_reward=True))
    retrained = ppo_job(config, tmp_path / "ppo", reward_run=reward, progress=False)["eval"]["mean_return"]
    random = random_policy_return(ENV_ID)
    normalised = (retrained - random) / (500.0 - random)
    print(f"fixed-horizon CartPole, PPO retrained on AIRL's g: {retrained:.1f}, normalised {normalised:.3f}")
    assert normalised >= 0.9
