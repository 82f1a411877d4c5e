"""Where a recovered reward goes wrong: its mean per step on the demos' steps, on a random policy's
and on the steps of given policies, beside the env's true reward per step and the Pearson
correlation of the two over each set's steps. A policy that earns as much of the recovered reward
per step as the demos at a random policy's true reward has found a state the reward rates wrongly.

    python bench/reward_on_states.py REWARD_RUN --env ID --demos F.mcap [--policy RUN ...]

A policy is a finished run (`train ppo`, `train irl`, ...) or an interrupted PPO run's
RUN.partial folder (its latest checkpoint). Vector observations only.
"""

from __future__ import annotations

import argparse
import json
from contextlib import closing
from pathlib import Path

import numpy as np
import torch
from safetensors.torch import load_file

import imitation.envs  # noqa: F401  (registers the ids)
from imitation.data.dataset import DemoDataset
from imitation.data.loader import load_transitions
from imitation.envs.make import make_env
from imitation.envs.rollout import collect_transitions
from imitation.policies import POLICY_PREFIX, ActorCritic, SingleObservationPolicy, make_policy
from imitation.policy_kinds import load_policy
from imitation.rewards import RewardNet, load_reward

Steps = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]  # s, a, s', true reward


def checkpoint_policy(partial: Path, env_id: str) -> ActorCritic:
    """The policy of an interrupted PPO run's latest checkpoint, built from its config's PPO fields."""
    ppo = json.loads((partial / "config.json").read_text())["ppo"]
    with closing(make_env(env_id)) as env:
        policy = make_policy(
            env.observation_space,
            env.action_space,
            hidden_sizes=ppo["hidden_sizes"],
            activation=ppo["activation"],
            shared_trunk=ppo["shared_trunk"],
            normalize_observations=ppo["normalize_observations"],
            log_std_init=ppo["log_std_init"],
        )
    tensors = load_file(str(partial / "checkpoint" / "tensors.safetensors"))
    policy.load_state_dict({k[len(POLICY_PREFIX) :]: v for k, v in tensors.items() if k.startswith(POLICY_PREFIX)})
    return policy.eval()


def recovered(reward: RewardNet, steps: Steps) -> np.ndarray:
    observations, actions, following, _ = steps
    with torch.no_grad():
        return (
            reward.rewards_of(torch.as_tensor(observations), torch.as_tensor(actions), torch.as_tensor(following))
            .double()
            .numpy()
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("reward", type=Path, help="a reward run directory (`train irl`)")
    parser.add_argument("--env", required=True)
    parser.add_argument("--demos", type=Path, required=True)
    parser.add_argument("--policy", type=Path, action="append", default=[], metavar="RUN")
    parser.add_argument("--episodes", type=int, default=3, help="episodes of each policy (default: 3)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    reward = load_reward(args.reward)
    demos = load_transitions(DemoDataset([args.demos]), next_observations=True)
    assert demos.next_observations is not None
    demo_steps = (np.asarray(demos.observations), np.asarray(demos.actions), np.asarray(demos.next_observations))
    sets: dict[str, Steps] = {"demos": (*demo_steps, demos.rewards)}
    with closing(make_env(args.env)) as env:
        space = env.action_space
        space.seed(args.seed)
        sets["random policy"] = collect_transitions(env, lambda _: space.sample(), episodes=args.episodes, seed=args.seed)
        for run in args.policy:
            policy = checkpoint_policy(run, args.env) if run.name.endswith(".partial") else load_policy(run)
            sets[str(run)] = collect_transitions(env, SingleObservationPolicy(policy), episodes=args.episodes, seed=args.seed)
    print(f"{args.reward} on {args.env}, {args.episodes} episodes per policy (the given ones deterministic)")
    print("| steps of | steps | recovered reward per step | true reward per step | Pearson |")
    print("|---|---:|---:|---:|---:|")
    for name, steps in sets.items():
        values, true = recovered(reward, steps), steps[3]
        pearson = np.corrcoef(values, true)[0, 1] if values.std() > 0 and true.std() > 0 else float("nan")
        print(f"| {name} | {len(true)} | {values.mean():.2f} | {true.mean():.3f} | {pearson:.2f} |")


if __name__ == "__main__":
    main()
