"""npz rollouts written by HumanCompatibleAI/imitation's own code, for tests/convert/test_npz.py.

imitation wrote its flat npz format up to version 0.3.x (later versions only read it), so this
runs imitation 0.3.2's `rollout.generate_trajectories` and `types.save` — never a project
dependency — in a side venv that borrows the main venv's numpy, torch and gymnasium:

    python3.12 -m venv bench/.venv-hcimitation
    echo "$PWD/.venv/lib/python3.12/site-packages" > bench/.venv-hcimitation/lib/python3.12/site-packages/main-venv.pth
    bench/.venv-hcimitation/bin/pip install --no-deps imitation==0.3.2 stable-baselines3==2.9.2
    cd /tmp && /work/main/bench/.venv-hcimitation/bin/python /work/main/tools/imitation_npz_fixtures.py

(Run it from outside the repository, so that `import imitation` finds imitation 0.3.2, not this
project.) `generate_trajectories` closes every trajectory with `terminal=True` when the vector env
reports `done`, and gymnasium's `done` (as stable-baselines3's DummyVecEnv reports it) is
`terminated or truncated`: the file cannot tell a time limit from a termination, which is what the
tests hold the converter to.

Each trajectory is collected alone, from a DummyVecEnv seeded with its own seed, so a test can
reset the env with that seed and replay the trajectory's actions (the seeds are written to
NAME.json beside NAME.npz, since imitation's format has no place for them). The policies are
hand-written controllers with per-episode noise, so that CartPole-v1 gives both episodes that fall
and episodes that last the 500-step time limit; Pendulum-v1 never terminates.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
from stable_baselines3.common.vec_env import DummyVecEnv

from imitation.data import rollout, types  # HumanCompatibleAI/imitation 0.3.2

if not Path(rollout.__file__).resolve().is_relative_to(Path(sys.prefix).resolve()):
    raise SystemExit(f"imports this project's imitation ({rollout.__file__}), not imitation 0.3.2: run it from outside the repo")

OUT = Path(__file__).resolve().parent.parent / "tests" / "fixtures" / "imitation"


def cartpole_policy(noise: float, rng: np.random.Generator):
    def act(observations: np.ndarray) -> np.ndarray:
        x, x_dot, theta, theta_dot = observations[0]
        action = int(theta + 0.5 * theta_dot + 0.05 * x + 0.2 * x_dot > 0)
        return np.array([1 - action if rng.random() < noise else action])

    return act


def pendulum_policy(noise: float, rng: np.random.Generator):
    def act(observations: np.ndarray) -> np.ndarray:
        cos, sin, velocity = observations[0]
        energy = 0.5 * velocity**2 + 10.0 * (cos - 1.0)  # 0 at the top
        torque = -8.0 * np.arctan2(sin, cos) - 2.0 * velocity if cos > 0.8 else np.sign(velocity or 1.0) * (energy < 0) * 2.0
        return np.clip(np.array([[torque + noise * rng.normal()]], dtype=np.float32), -2.0, 2.0)

    return act


def collect(env_id: str, policy, seed: int) -> types.TrajectoryWithRew:
    venv = DummyVecEnv([lambda: gym.make(env_id)])
    venv.seed(seed)
    (trajectory,) = rollout.generate_trajectories(policy, venv, rollout.make_min_episodes(1), np.random.default_rng(seed))
    venv.close()
    return trajectory


def write(name: str, env_id: str, make_policy, noises: list[float]) -> None:
    seeds = list(range(len(noises)))
    trajectories = [collect(env_id, make_policy(noise, np.random.default_rng(1000 + seed)), seed) for seed, noise in zip(seeds, noises)]
    types.save(OUT / f"{name}.npz", trajectories)  # imitation 0.3.2's own writer
    lengths = [len(t) for t in trajectories]
    (OUT / f"{name}.json").write_text(
        json.dumps(
            {
                "env_id": env_id,
                "written_by": "imitation 0.3.2 rollout.generate_trajectories + types.save (tools/imitation_npz_fixtures.py)",
                "reset_seeds": seeds,
                "lengths": lengths,
                "terminal": [bool(t.terminal) for t in trajectories],
            },
            indent=1,
        )
        + "\n"
    )
    print(f"{name}: {len(trajectories)} trajectories of {env_id}, lengths {lengths}")


def main() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    write("cartpole", "CartPole-v1", cartpole_policy, [0.0, 0.35, 0.05, 0.5, 0.0, 0.45, 0.1, 0.4, 0.0, 0.6])
    write("pendulum", "Pendulum-v1", pendulum_policy, [0.0, 0.5, 1.0])


if __name__ == "__main__":
    main()
