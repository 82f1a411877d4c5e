"""How well the fixed-horizon MuJoCo tasks' true reward estimates the forward speed.

The observations leave out x, so `imitation.envs.true_rewards` estimates the speed over a step,
(x(s') − x(s))/dt, by the trapezoid rule from the x velocities the observations hold at both ends.
This prints, per task, the Pearson correlation of that estimate and of the s' velocity alone with
the env's own speed (`info["x_velocity"]`) over uniformly random steps, and the EPIC floor the
estimate leaves, √((1 − ρ)/2).

Usage: python bench/true_reward_speed.py [--steps 1000]
"""

from __future__ import annotations

import argparse

import numpy as np

import imitation.envs  # noqa: F401 - registers the imitation/ envs
from imitation.envs.make import make_env

SPEED_INDEX = {"HalfCheetah": 8, "Hopper": 5, "Walker2d": 8, "Swimmer": 3, "Ant": 13}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=1000, help="random steps per task from reset(seed=0)")
    args = parser.parse_args()
    print(f"{args.steps} uniformly random steps per task, no resets (nothing ends before 1000)")
    print("| task | ρ, trapezoid (ẋ(s) + ẋ(s'))/2 | ρ, ẋ(s') alone | EPIC floor of the trapezoid |")
    print("|---|---:|---:|---:|")
    for name, index in SPEED_INDEX.items():
        env = make_env(f"imitation/{name}FixedHorizon-v0")
        env.action_space.seed(0)
        observation, _ = env.reset(seed=0)
        before, after, speeds = [], [], []
        for _ in range(args.steps):
            next_observation, _, _, _, info = env.step(env.action_space.sample())
            before.append(observation[index])
            after.append(next_observation[index])
            speeds.append(info["x_velocity"])
            observation = next_observation
        trapezoid = np.corrcoef(0.5 * (np.array(before) + np.array(after)), speeds)[0, 1]
        newest = np.corrcoef(after, speeds)[0, 1]
        print(f"| {name} | {trapezoid:.5f} | {newest:.3f} | {np.sqrt((1 - trapezoid) / 2):.3f} |")


if __name__ == "__main__":
    main()
