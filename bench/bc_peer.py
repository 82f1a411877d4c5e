"""Worker for bench/bc.py: one BC run of HumanCompatibleAI/imitation 1.0.1, in its own venv.

Runs under bench/.venv-imitation/bin/python (Python 3.11, gymnasium 0.29), where `imitation` is
HumanCompatibleAI's package, never ours: bench/bc.py starts this script without our checkout on
PYTHONPATH. Usage: bc_peer.py SPEC.json RESULT.json, where the spec holds data, hidden_sizes,
batch_size, epochs, runs, seed and eval_episodes; the result holds samples_per_second (one per
run) and, when eval_episodes > 0, the last run's deterministic CartPole-v1 returns on seeds
0..eval_episodes-1.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from imitation.algorithms import bc
from imitation.data.types import Transitions
from stable_baselines3.common.policies import ActorCriticPolicy


def load_transitions(path: str) -> Transitions:
    """The SB2-format expert npz as imitation's Transitions (s' is the next step's observation)."""
    data = np.load(path)
    obs = data["obs"].astype(np.float32)
    acts = data["actions"].reshape(-1).astype(np.int64)
    starts = data["episode_starts"].astype(bool)
    dones = np.append(starts[1:], True)
    # The last step of an episode has no successor in the file; BC never reads s', so repeat s.
    next_obs = np.where(dones[:, None], obs, np.roll(obs, -1, axis=0))
    infos = np.array([{} for _ in range(len(obs))])
    return Transitions(obs=obs, acts=acts, infos=infos, next_obs=next_obs, dones=dones)


def evaluate(policy: ActorCriticPolicy, episodes: int) -> list[float]:
    """Deterministic returns on CartPole-v1, episode i reset with seed i (as ours is evaluated)."""
    env = gym.make("CartPole-v1")
    returns = []
    for seed in range(episodes):
        obs, _ = env.reset(seed=seed)
        total, done = 0.0, False
        while not done:
            action, _ = policy.predict(obs, deterministic=True)
            obs, reward, terminated, truncated, _ = env.step(int(action))
            total += float(reward)
            done = terminated or truncated
        returns.append(total)
    env.close()
    return returns


def make_trainer(env: gym.Env, transitions: Transitions, spec: dict[str, Any]) -> bc.BC:
    """Their BC on a fresh ActorCriticPolicy with the same MLP as ours."""
    # Separate actor/critic trunks of hidden_sizes with ReLU, as our BC default.
    policy = ActorCriticPolicy(
        env.observation_space,
        env.action_space,
        lr_schedule=lambda _: 1e-3,  # unused: BC builds its own Adam (lr 1e-3, as ours)
        net_arch=list(spec["hidden_sizes"]),
        activation_fn=torch.nn.ReLU,
    )
    return bc.BC(
        observation_space=env.observation_space,
        action_space=env.action_space,
        rng=np.random.default_rng(spec["seed"]),
        policy=policy,
        demonstrations=transitions,
        batch_size=spec["batch_size"],
        device="cpu",
    )


def run(spec: dict[str, Any]) -> dict[str, Any]:
    """Build the data and, per run, the trainer (untimed); time each bc.train; evaluate the last."""
    torch.set_num_threads(1)
    transitions = load_transitions(spec["data"])
    # Their loader drops the last incomplete batch (drop_last=True): count only what it trains on.
    samples = spec["epochs"] * (len(transitions) // spec["batch_size"]) * spec["batch_size"]
    env = gym.make("CartPole-v1")
    speeds = []
    # Identical runs with a fresh policy each: the first pays one-time lazy initialisation (cold),
    # the later ones show steady-state training speed (warm), as on our side.
    for _ in range(spec["runs"]):
        torch.manual_seed(spec["seed"])
        trainer = make_trainer(env, transitions, spec)
        started = time.perf_counter()
        # A huge log_interval leaves only batch 0 logged: the logger's stdout dump is not training work.
        trainer.train(n_epochs=spec["epochs"], progress_bar=False, log_interval=10**9)
        speeds.append(samples / (time.perf_counter() - started))
    result: dict[str, Any] = {"samples_per_second": speeds}
    if spec["eval_episodes"] > 0:
        result["returns"] = evaluate(trainer.policy, spec["eval_episodes"])
    return result


def main() -> None:
    spec_path, result_path = sys.argv[1], sys.argv[2]
    result = run(json.loads(Path(spec_path).read_text()))
    Path(result_path).write_text(json.dumps(result))


if __name__ == "__main__":
    main()
