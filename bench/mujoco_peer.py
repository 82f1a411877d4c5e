"""Worker for bench/mujoco_table.py: one BC or GAIL run of HumanCompatibleAI/imitation 1.0.1 on MuJoCo.

Runs under bench/.venv-imitation/bin/python (Python 3.11, gymnasium 0.29.1, stable-baselines3
2.2.1, torch 2.13.0 CPU; made by bench/bc.py's `ensure_imitation_venv()`), where `imitation` is
HumanCompatibleAI's package, never ours: start it with cwd=bench/, our checkout off PYTHONPATH and
OMP_NUM_THREADS=MKL_NUM_THREADS=1. That venv has no MuJoCo; the orchestrator adds it once with
`bench/.venv-imitation/bin/python -m pip install mujoco==4.0.1 imageio` (PEER_MUJOCO below:
gymnasium 0.29.1's `mujoco` extra is mujoco>=2.3.3 plus imageio, which its v4 envs import;
4.0.1 is the MuJoCo our own venv runs, so both sides simulate with the same engine).

Usage: mujoco_peer.py SPEC.json RESULT.json.

SPEC.json: method ("bc" or "gail"), env ("HalfCheetah" or "Hopper"), demos (an .npz of float32
obs (N, d), acts (N, k), next_obs (N, d) and bool dones (N,), true on the last step of each
episode), seed, eval_episodes, for gail total_timesteps, and optionally log_dir (where their
logger writes progress.csv: BC every 500 batches, GAIL every round; without it nothing is logged,
instead of the default stdout table and files under /tmp).
RESULT.json: returns (deterministic returns, episode i reset with seed i), mean_return, seconds
(wall time of the training call alone: `BC.train` / `GAIL.train`; building and evaluation
excluded), timesteps (gail: environment steps actually trained on, a multiple of 4096) and
steps_per_second (gail), and settings (everything actually used).

The env: ours are gymnasium 1.x v5 HalfCheetah / Hopper (terminate_when_unhealthy=False) with a
1000-step TimeLimit (imitation/{HalfCheetah,Hopper}FixedHorizon-v0). gymnasium 0.29 has no v5, so
this uses gym.make("HalfCheetah-v4") and gym.make("Hopper-v4", terminate_when_unhealthy=False),
max_episode_steps=1000: the same 17- and 11-dim observations; with mujoco 4.0.1 both sides give
bit-identical observations and rewards for the same seed and actions (checked on 1000 random
steps of each, Hopper's healthy bonus included: v4 also pays it only while healthy when
terminate_when_unhealthy=False).

Hyperparameters: imitation's tuned benchmark configs, the files shipped in the 1.0.1 wheel as
imitation/scripts/config/tuned_hps/*.json (identical to benchmarking/*_best_hp_eval.json in
HumanCompatibleAI/imitation), tuned there on seals/HalfCheetah-v1 and seals/Hopper-v1 (which
differ from ours only by an extra x-position observation):
- BC, from bc_seals_half_cheetah_best_hp_eval.json / bc_seals_hopper_best_hp_eval.json:
  batch_size 64, Adam at lr 0.008056922426724927 / 0.0007172435323620212, l2_weight
  0.005728455628518169 / 1.3610189916104634e-6, 20 epochs, log_interval 500; policy
  FeedForward32Policy (separate [32, 32] tanh trunks for actor and critic) with
  NormalizeFeaturesExtractor(RunningNorm). Everything else is BC's default (ent_weight 1e-3).
  (1.0.1's own train_imitation script drops that policy: its `make_or_load_policy` forgets to
  return it, so BC falls back to FeedForward32Policy without observation normalisation. This
  worker uses the policy the config names.)
- GAIL, from gail_seals_half_cheetah_best_hp_eval.json / gail_seals_hopper_best_hp_eval.json,
  built as imitation/scripts/train_adversarial.py builds it: reward net
  NormalizedRewardNet(BasicRewardNet(normalize_input_layer=RunningNorm), RunningNorm);
  n_disc_updates_per_round 8, demo_batch_size 8192 / 128, gen_replay_buffer_capacity 512 / 4096;
  generator sb3 PPO with rl batch 4096 steps a round over 8 envs (n_steps 512; num_vec 8 is the
  environment ingredient's default, scripts/ingredients/environment.py), PPO batch_size 64 / 512,
  n_epochs 5 / 20, learning_rate 0.00026250519057717037 / 4.3984856156897565e-5, gamma
  0.95 / 0.995, gae_lambda 0.95 / 0.98, clip_range 0.1 / 0.1, ent_coef 3.992371122209408e-6 /
  0.001255299425412744, vf_coef 0.11483689492120866 / 0.20315938606555833, max_grad_norm
  0.8 / 0.9; PPO's policy FeedForward32Policy (HalfCheetah) / MlpPolicy with separate [64, 64]
  ReLU trunks (Hopper), both with NormalizeFeaturesExtractor(RunningNorm). Their configs train
  for 10,000,000 timesteps; SPEC's total_timesteps sets ours. Their script steps the 8 envs in
  subprocesses; this worker uses a DummyVecEnv (one process, one core), each env made by
  imitation.util.util.make_vec_env (Monitor, TimeLimit, per-env seeds drawn from the seed).
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

# ruff: noqa: I001 (isort would take their `imitation` for our first-party package)
import gymnasium as gym
import numpy as np
import torch
from imitation.algorithms import bc
from imitation.algorithms.adversarial.gail import GAIL
from imitation.data import wrappers
from imitation.data.types import Transitions
from imitation.policies.base import FeedForward32Policy, NormalizeFeaturesExtractor
from imitation.rewards.reward_nets import BasicRewardNet, NormalizedRewardNet
from imitation.util import logger as imitation_logger
from imitation.util.networks import RunningNorm
from imitation.util.util import make_vec_env
from stable_baselines3 import PPO

PEER_MUJOCO = "mujoco==4.0.1"  # pip install PEER_MUJOCO imageio into bench/.venv-imitation
HORIZON = 1000
ENVS = {"HalfCheetah": ("HalfCheetah-v4", {}), "Hopper": ("Hopper-v4", {"terminate_when_unhealthy": False})}
NORMALIZED_FEATURES = {
    "features_extractor_class": NormalizeFeaturesExtractor,
    "features_extractor_kwargs": {"normalize_class": RunningNorm},
}

# imitation/scripts/config/tuned_hps/bc_seals_{half_cheetah,hopper}_best_hp_eval.json
BC_SETTINGS = {
    "HalfCheetah": {
        "batch_size": 64,
        "l2_weight": 0.005728455628518169,
        "lr": 0.008056922426724927,
        "n_epochs": 20,
        "log_interval": 500,
    },
    "Hopper": {
        "batch_size": 64,
        "l2_weight": 1.3610189916104634e-6,
        "lr": 0.0007172435323620212,
        "n_epochs": 20,
        "log_interval": 500,
    },
}
# imitation/scripts/config/tuned_hps/gail_seals_{half_cheetah,hopper}_best_hp_eval.json; n_envs is
# the environment ingredient's num_vec default, n_steps = rl.batch_size 4096 // n_envs.
GAIL_SETTINGS = {
    "HalfCheetah": {
        "n_envs": 8,
        "algorithm": {"demo_batch_size": 8192, "gen_replay_buffer_capacity": 512, "n_disc_updates_per_round": 8},
        "ppo": {
            "n_steps": 512,
            "batch_size": 64,
            "clip_range": 0.1,
            "ent_coef": 3.992371122209408e-6,
            "gae_lambda": 0.95,
            "gamma": 0.95,
            "learning_rate": 0.00026250519057717037,
            "max_grad_norm": 0.8,
            "n_epochs": 5,
            "vf_coef": 0.11483689492120866,
        },
        "policy": "FeedForward32Policy+RunningNorm",
    },
    "Hopper": {
        "n_envs": 8,
        "algorithm": {"demo_batch_size": 128, "gen_replay_buffer_capacity": 4096, "n_disc_updates_per_round": 8},
        "ppo": {
            "n_steps": 512,
            "batch_size": 512,
            "clip_range": 0.1,
            "ent_coef": 0.001255299425412744,
            "gae_lambda": 0.98,
            "gamma": 0.995,
            "learning_rate": 4.3984856156897565e-5,
            "max_grad_norm": 0.9,
            "n_epochs": 20,
            "vf_coef": 0.20315938606555833,
        },
        "policy": "MlpPolicy(net_arch=dict(pi=[64, 64], vf=[64, 64]), activation_fn=ReLU)+RunningNorm",
    },
}


def make_env(name: str) -> gym.Env:
    """The v4 stand-in for our fixed-horizon v5 task (see the module docstring)."""
    gym_id, kwargs = ENVS[name]
    return gym.make(gym_id, max_episode_steps=HORIZON, **kwargs)


def load_transitions(path: str) -> Transitions:
    """The demo npz as imitation's Transitions."""
    data = np.load(path)
    obs = data["obs"].astype(np.float32)
    infos = np.array([{} for _ in range(len(obs))])
    return Transitions(
        obs=obs,
        acts=data["acts"].astype(np.float32),
        infos=infos,
        next_obs=data["next_obs"].astype(np.float32),
        dones=data["dones"].astype(bool),
    )


def evaluate(policy: Any, name: str, episodes: int) -> list[float]:
    """Deterministic returns, episode i reset with seed i (as ours is evaluated)."""
    env = make_env(name)
    returns = []
    for seed in range(episodes):
        obs, _ = env.reset(seed=seed)
        total, done = 0.0, False
        while not done:
            action, _ = policy.predict(obs, deterministic=True)
            obs, reward, terminated, truncated, _ = env.step(action)
            total += float(reward)
            done = terminated or truncated
        returns.append(total)
    env.close()
    return returns


def run_bc(spec: dict[str, Any], transitions: Transitions, logger: Any) -> tuple[Any, dict[str, Any]]:
    settings = BC_SETTINGS[spec["env"]]
    env = make_env(spec["env"])
    policy = FeedForward32Policy(
        observation_space=env.observation_space,
        action_space=env.action_space,
        lr_schedule=lambda _: 1.0,  # unused: BC builds its own optimizer (as their policy ingredient)
        **NORMALIZED_FEATURES,
    )
    trainer = bc.BC(
        observation_space=env.observation_space,
        action_space=env.action_space,
        rng=np.random.default_rng(spec["seed"]),
        policy=policy,
        demonstrations=transitions,
        batch_size=settings["batch_size"],
        l2_weight=settings["l2_weight"],
        optimizer_cls=torch.optim.Adam,
        optimizer_kwargs={"lr": settings["lr"]},
        device="cpu",
        custom_logger=logger,
    )
    started = time.perf_counter()
    trainer.train(n_epochs=settings["n_epochs"], log_interval=settings["log_interval"], progress_bar=False)
    seconds = time.perf_counter() - started
    used = dict(
        settings,
        policy="FeedForward32Policy+RunningNorm",
        ent_weight=trainer.loss_calculator.ent_weight,
        transitions=len(transitions),
    )
    return trainer.policy, {"seconds": seconds, "settings": used}


def run_gail(spec: dict[str, Any], transitions: Transitions, logger: Any) -> tuple[Any, dict[str, Any]]:
    settings = GAIL_SETTINGS[spec["env"]]
    gym_id, env_kwargs = ENVS[spec["env"]]
    venv = make_vec_env(
        gym_id,
        rng=np.random.default_rng(spec["seed"]),
        n_envs=settings["n_envs"],
        parallel=False,
        max_episode_steps=HORIZON,
        env_make_kwargs=env_kwargs,
        post_wrappers=[lambda env, _: wrappers.RolloutInfoWrapper(env)],
    )
    if spec["env"] == "HalfCheetah":
        policy_cls, policy_kwargs = FeedForward32Policy, dict(NORMALIZED_FEATURES)
    else:
        policy_cls = "MlpPolicy"
        policy_kwargs = dict(NORMALIZED_FEATURES, activation_fn=torch.nn.ReLU, net_arch=dict(pi=[64, 64], vf=[64, 64]))
    generator = PPO(policy_cls, venv, policy_kwargs=policy_kwargs, seed=spec["seed"], device="cpu", **settings["ppo"])
    reward_net = NormalizedRewardNet(
        BasicRewardNet(venv.observation_space, venv.action_space, normalize_input_layer=RunningNorm),
        RunningNorm,
    )
    trainer = GAIL(
        demonstrations=transitions,
        venv=venv,
        gen_algo=generator,
        reward_net=reward_net,
        custom_logger=logger,
        **settings["algorithm"],
    )
    started = time.perf_counter()
    trainer.train(int(spec["total_timesteps"]))
    seconds = time.perf_counter() - started
    venv.close()
    timesteps = int(spec["total_timesteps"]) // trainer.gen_train_timesteps * trainer.gen_train_timesteps
    used = dict(settings, total_timesteps=int(spec["total_timesteps"]), vec_env="DummyVecEnv", transitions=len(transitions))
    return trainer.policy, {
        "seconds": seconds,
        "timesteps": timesteps,
        "steps_per_second": timesteps / seconds,
        "settings": used,
    }


def run(spec: dict[str, Any]) -> dict[str, Any]:
    torch.set_num_threads(1)
    torch.manual_seed(spec["seed"])
    transitions = load_transitions(spec["demos"])
    if spec["method"] not in ("bc", "gail"):
        raise SystemExit(f"mujoco_peer.py: unknown method {spec['method']!r}")
    with tempfile.TemporaryDirectory(prefix="mujoco-peer-") as scratch:
        log_dir = spec.get("log_dir")
        logger = imitation_logger.configure(log_dir or scratch, format_strs=["csv"] if log_dir else [])
        policy, result = (run_bc if spec["method"] == "bc" else run_gail)(spec, transitions, logger)
    returns = evaluate(policy, spec["env"], spec["eval_episodes"])
    result["settings"].update(
        method=spec["method"],
        env=ENVS[spec["env"]][0],
        env_kwargs=ENVS[spec["env"]][1],
        max_episode_steps=HORIZON,
        seed=spec["seed"],
    )
    return {"returns": returns, "mean_return": float(np.mean(returns)) if returns else None, **result}


def main() -> None:
    spec_path, result_path = sys.argv[1], sys.argv[2]
    result = run(json.loads(Path(spec_path).read_text()))
    Path(result_path).write_text(json.dumps(result))


if __name__ == "__main__":
    main()
