"""Per-environment presets in one table, like rl-baselines3-zoo's hyperparams: the PPO settings
that make `train ppo --env ID` work without flags, and how long the reward-learning jobs run.

rl-baselines3-zoo's tuned PPO settings where we have them (Pendulum, and HalfCheetah's policy beside
a reward being learnt, depart from them, see there), CleanRL's defaults otherwise. The figures
behind each choice are in bench/RESULTS.md.
"""

from __future__ import annotations

from contextlib import closing
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym

from imitation.algorithms.ppo import PPOConfig
from imitation.envs.make import make_env
from imitation.envs.pixels import image_keys


@dataclass(frozen=True)
class EnvPreset:
    ppo: dict[str, Any] = field(default_factory=dict)  # PPOConfig fields
    # PPOConfig fields of the policy `train irl` trains beside the reward it is learning (GAIL's
    # generator, AIRL's and GCL's policy), where they differ from `ppo`; None: `ppo`. A reward
    # already learnt (`train ppo --reward`, `eval reward`'s retraining) is fixed, like the env's
    # own, and gets `ppo`.
    irl_ppo: dict[str, Any] | None = None
    irl_steps: int = 200_000  # PPO steps of `train irl --method gcl|gail|airl`
    retrain_steps: int = 200_000  # PPO steps of each retraining in `eval reward`


_CARTPOLE = dict(n_envs=8, n_steps=32, batch_size=256, gamma=0.98, gae_lambda=0.8, n_epochs=20, learning_rate=1e-3)
_CONTINUOUS = dict(
    n_envs=1, n_steps=2048, batch_size=64, n_epochs=10, learning_rate=3e-4, normalize_observations=True, normalize_rewards=True
)
# rl-baselines3-zoo's tuned HalfCheetah PPO (DLR-RM/rl-baselines3-zoo hyperparams/ppo.yml, HalfCheetah-v3,
# its `normalize: true` as both normalisers), but for its ortho_init=False: our layers keep their
# orthogonal init.
_HALFCHEETAH = dict(
    n_envs=1,
    n_steps=512,
    batch_size=64,
    gamma=0.98,
    learning_rate=2.0633e-05,
    anneal_lr=False,
    entropy_coef=0.000401762,
    clip_range=0.1,
    n_epochs=20,
    gae_lambda=0.92,
    max_grad_norm=0.8,
    value_coef=0.58096,
    log_std_init=-2.0,
    activation="relu",
    hidden_sizes=[256, 256],
    normalize_observations=True,
    normalize_rewards=True,
)
# Image observations (--pixels, or an env that observes images), whatever the env: the settings
# tuned for an MLP on the state (CartPole's 20 epochs over 256-step rollouts) do not carry over to
# a CNN, so rl-baselines3-zoo's PPO for Atari (DLR-RM/rl-baselines3-zoo hyperparams/ppo.yml,
# "atari": n_envs 8, n_steps 128, n_epochs 4, batch_size 256, learning_rate lin_2.5e-4,
# clip_range lin_0.1, vf_coef 0.5, ent_coef 0.01; gamma and gae_lambda SB3's 0.99 and 0.95,
# PPOConfig's defaults too). Unlike the zoo, the clip range stays at 0.1 (only the learning rate
# is annealed), and its frame_stack 4 is left to --frame-stack: a pixel reward fixes the stack.
_PIXELS = dict(
    n_envs=8,
    n_steps=128,
    n_epochs=4,
    batch_size=256,
    learning_rate=2.5e-4,
    anneal_lr=True,
    clip_range=0.1,
    entropy_coef=0.01,
    value_coef=0.5,
)

PRESETS: dict[str, EnvPreset] = {
    "CartPole-v1": EnvPreset(ppo=_CARTPOLE),
    # The zoo reaches Pendulum with gSDE; with a state-independent log-std, an entropy bonus keeps
    # σ from collapsing before the swing-up is found.
    "Pendulum-v1": EnvPreset(
        ppo=dict(
            n_envs=4,
            n_steps=1024,
            batch_size=64,
            gamma=0.9,
            gae_lambda=0.95,
            n_epochs=10,
            learning_rate=1e-3,
            normalize_observations=True,
            log_std_init=-0.5,
            entropy_coef=0.01,
        ),
        irl_steps=500_000,
        retrain_steps=600_000,
    ),
    "MountainCarContinuous-v0": EnvPreset(
        ppo=dict(n_envs=1, n_steps=2048, batch_size=64, n_epochs=10, learning_rate=3e-4, normalize_observations=True),
    ),
    # Without termination, most early steps are spent after the fall, where nothing can be
    # learnt, and the policy turns near-deterministic early: an entropy bonus keeps it exploring.
    "imitation/CartPoleFixedHorizon-v0": EnvPreset(
        ppo=_CARTPOLE | {"entropy_coef": 0.01}, irl_steps=200_000, retrain_steps=300_000
    ),
    # The fixed-horizon MuJoCo tasks: the continuous-control PPO settings, and the budgets at which
    # AIRL met the MuJoCo table's bars.
    **{
        f"imitation/{task}FixedHorizon-v0": EnvPreset(ppo=_CONTINUOUS, irl_steps=1_000_000, retrain_steps=300_000)
        for task in ("Hopper", "Walker2d", "Swimmer", "Ant")
    },
    # The zoo's tuned HalfCheetah PPO learns the task's own reward far better than the continuous-
    # control settings, and retrains on AIRL's g where they can fail; as GAIL's generator, beside a
    # discriminator still learning, it did worse: `train irl`'s policy keeps the continuous-control
    # settings. AIRL needs three times Hopper's steps here.
    "imitation/HalfCheetahFixedHorizon-v0": EnvPreset(
        ppo=_HALFCHEETAH, irl_ppo=_CONTINUOUS, irl_steps=3_000_000, retrain_steps=300_000
    ),
}


def preset(env_id: str) -> EnvPreset:
    return PRESETS.get(env_id, EnvPreset())


def ppo_settings(
    env_id: str,
    action_space: gym.Space | None = None,
    *,
    learned_reward: bool = False,
    beside_irl: bool = False,
    images: bool = False,
) -> dict[str, Any]:
    """PPOConfig fields for `env_id`: the pixel preset when the policy sees `images`, else the
    env's preset (`beside_irl`, the policy of an IRL run: its `irl_ppo` if it has one), else the
    continuous-control defaults for Box actions. On a learned reward (`beside_irl` is one), rewards
    are scaled by their running return std, since a learned reward's scale is arbitrary (and
    drifts while it is being learned)."""
    if images:
        settings = dict(_PIXELS)
    elif env_id in PRESETS:
        chosen = PRESETS[env_id]
        beside = chosen.irl_ppo if beside_irl else None
        settings = dict(chosen.ppo if beside is None else beside)
    else:
        settings = dict(_CONTINUOUS) if isinstance(action_space, gym.spaces.Box) else {}
    return settings | ({"normalize_rewards": True} if learned_reward or beside_irl else {})


def ppo_config(env_id: str, *, learned_reward: bool = False, beside_irl: bool = False, **fields: Any) -> PPOConfig:
    """A PPOConfig for `env_id`: its preset (`ppo_settings`, which may need the env's spaces:
    the env is made to read them; rendered frames, `fields["pixels"]`, are images), then
    `fields` over it."""
    with closing(make_env(env_id)) as env:
        images = fields.get("pixels") is not None or bool(image_keys(env.observation_space))
        settings = ppo_settings(env_id, env.action_space, learned_reward=learned_reward, beside_irl=beside_irl, images=images)
    return PPOConfig(env_id=env_id, **settings | fields)
