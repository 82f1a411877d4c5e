"""Real stable-baselines3 zips and SB3's own actions on them, for tests/experts/test_sb3_algorithms.py.

Run with an interpreter that has stable-baselines3 and sb3-contrib (never a project dependency):

    python3.12 -m venv bench/.venv-sb3fix
    echo "$PWD/.venv/lib/python3.12/site-packages" > bench/.venv-sb3fix/lib/python3.12/site-packages/main-venv.pth
    bench/.venv-sb3fix/bin/pip install --no-deps stable-baselines3==2.9.2 sb3-contrib==2.9.0
    bench/.venv-sb3fix/bin/python tools/sb3_fixtures.py

It trains, with SB3 itself, the layouts the zoo snapshot in ../shared/testdata lacks (TD3, SAC
without gSDE, DQN on discrete observations) and writes their zips to tests/fixtures/sb3/; then,
for those and for every zoo zip it finds, SB3's deterministic `predict` on 256 observations of
the env (from a seeded random policy) and its mean return over episodes seeded 0-9, to
tests/fixtures/sb3/NAME.reference.npz. The tests hold our loader to those actions.
"""

from __future__ import annotations

import json
import sys
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np

warnings.filterwarnings("ignore")

from sb3_contrib import QRDQN, TQC  # noqa: E402
from stable_baselines3 import DQN, PPO, SAC, TD3  # noqa: E402
from stable_baselines3.common.noise import NormalActionNoise  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "tests" / "fixtures" / "sb3"
TESTDATA = ROOT.parent / "shared" / "testdata" / "experts"
ZOO = [
    ("zoo_sac_MountainCarContinuous-v0", SAC, TESTDATA / "zoo/sac_MountainCarContinuous-v0/MountainCarContinuous-v0.zip", "MountainCarContinuous-v0"),
    ("zoo_tqc_Pendulum-v1", TQC, TESTDATA / "zoo/tqc_Pendulum-v1/Pendulum-v1.zip", "Pendulum-v1"),
    ("zoo_dqn_CartPole-v1", DQN, TESTDATA / "zoo/dqn_CartPole-v1/CartPole-v1.zip", "CartPole-v1"),
    ("zoo_qrdqn_CartPole-v1", QRDQN, TESTDATA / "zoo/qrdqn_CartPole-v1/CartPole-v1.zip", "CartPole-v1"),
    ("zoo_sac_HalfCheetah-v3", SAC, TESTDATA / "zoo/sac_HalfCheetah-v3/HalfCheetah-v3.zip", "HalfCheetah-v5"),
    ("zoo_sac_Hopper-v3", SAC, TESTDATA / "zoo/sac_Hopper-v3/Hopper-v3.zip", "Hopper-v5"),
    ("ppo_CartPole-v1", PPO, TESTDATA / "sb3_ppo_cartpole/CartPole-v1.zip", "CartPole-v1"),
]


def train_fixtures() -> list[tuple[str, type, Path, str]]:
    """Small experts trained here with the zoo's hyperparameters for the env (smaller networks,
    so that the zips stay small): TD3 and SAC (no gSDE) on Pendulum-v1, DQN on FrozenLake-v1."""
    made = []
    pendulum = gym.make("Pendulum-v1")
    td3 = TD3(
        "MlpPolicy", pendulum, learning_rate=1e-3, gamma=0.98, buffer_size=200_000, learning_starts=10_000, gradient_steps=1,
        train_freq=1, action_noise=NormalActionNoise(np.zeros(1), 0.1 * np.ones(1)), policy_kwargs={"net_arch": [64, 64]}, seed=0,
        device="cpu",
    )
    td3.learn(20_000)
    td3.save(OUT / "td3_Pendulum-v1.zip")
    made.append(("td3_Pendulum-v1", TD3, OUT / "td3_Pendulum-v1.zip", "Pendulum-v1"))
    sac = SAC(
        "MlpPolicy", pendulum, learning_rate=1e-3, policy_kwargs={"net_arch": [64, 64]}, learning_starts=1_000, seed=0, device="cpu",
    )
    sac.learn(20_000)
    sac.save(OUT / "sac_Pendulum-v1.zip")
    made.append(("sac_Pendulum-v1", SAC, OUT / "sac_Pendulum-v1.zip", "Pendulum-v1"))
    lake = gym.make("FrozenLake-v1", is_slippery=False)
    dqn = DQN(
        "MlpPolicy", lake, learning_rate=1e-3, learning_starts=500, exploration_fraction=0.5, policy_kwargs={"net_arch": [32]},
        seed=0, device="cpu",
    )
    dqn.learn(10_000)
    dqn.save(OUT / "dqn_FrozenLake-v1.zip")
    made.append(("dqn_FrozenLake-v1", DQN, OUT / "dqn_FrozenLake-v1.zip", "FrozenLake-v1"))
    return made


def reference(name: str, algorithm: type, path: Path, env_id: str) -> None:
    kwargs = {"is_slippery": False} if env_id == "FrozenLake-v1" else {}
    env = gym.make(env_id, **kwargs)
    custom = {
        "learning_rate": 0.0, "lr_schedule": lambda _: 0.0, "exploration_schedule": lambda _: 0.0, "clip_range": lambda _: 0.0,
        "observation_space": env.observation_space, "action_space": env.action_space,
    }
    model = algorithm.load(path, custom_objects=custom, device="cpu")
    env.action_space.seed(0)
    observations, observation = [], env.reset(seed=0)[0]
    for _ in range(256):
        observations.append(observation)
        observation, _, terminated, truncated, _ = env.step(env.action_space.sample())
        if terminated or truncated:
            observation = env.reset()[0]
    observations = np.asarray(observations)
    actions, _ = model.predict(observations, deterministic=True)
    returns = []
    for seed in range(10):
        observation, done, total = env.reset(seed=seed)[0], False, 0.0
        while not done:
            action, _ = model.predict(observation, deterministic=True)
            if isinstance(env.action_space, gym.spaces.Discrete):
                action = int(action)
            observation, reward, terminated, truncated, _ = env.step(action)
            total += float(reward)
            done = terminated or truncated
        returns.append(total)
    np.savez_compressed(OUT / f"{name}.reference.npz", observations=observations, actions=actions, returns=np.asarray(returns))
    print(json.dumps({"name": name, "env": env_id, "mean_return": float(np.mean(returns)), "std_return": float(np.std(returns))}), flush=True)


def main() -> int:
    OUT.mkdir(parents=True, exist_ok=True)
    trained = [
        (path.stem, {"td3": TD3, "sac": SAC, "dqn": DQN}[path.stem.split("_")[0]], path, path.stem.split("_", 1)[1])
        for path in sorted(OUT.glob("*.zip"))
    ]
    todo = train_fixtures() if "--no-train" not in sys.argv else trained
    for name, algorithm, path, env_id in todo + [entry for entry in ZOO if entry[2].is_file()]:
        try:
            reference(name, algorithm, path, env_id)
        except gym.error.DependencyNotInstalled as error:
            print(f"{name}: skipped ({error})", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
