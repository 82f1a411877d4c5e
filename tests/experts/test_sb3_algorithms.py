"""Experts of every algorithm in rl-baselines3-zoo, read from real stable-baselines3 zips without
unpickling, act exactly as SB3's own `predict(deterministic=True)` does.

The zips: the zoo's trained agents in ../shared/testdata (SAC with gSDE, TQC, DQN, QR-DQN, PPO,
and MuJoCo SACs where MuJoCo is installed) and, for the layouts the zoo snapshot lacks (TD3, SAC
without gSDE, DQN on discrete observations), zips that SB3 itself trained and saved, in
tests/fixtures/sb3. SB3's actions on 256 observations of each env, and its mean return over
episodes seeded 0-9, were recorded beside them by tools/sb3_fixtures.py, run with SB3 in a side
venv (never a dependency of this project)."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from support import REPO, run_cli
from test_cli import assert_one_line_error, last_json

from imitation.errors import ImitationError
from imitation.evaluation.policy import evaluate_policy
from imitation.experts.sb3 import load_sb3_expert, load_sb3_policy
from imitation.policies import SingleObservationPolicy

FIXTURES = REPO / "tests" / "fixtures" / "sb3"
# name: (zip, env id, the algorithm the loader must name)
TRAINED = {
    "td3_Pendulum-v1": (FIXTURES / "td3_Pendulum-v1.zip", "Pendulum-v1", "TD3"),
    "sac_Pendulum-v1": (FIXTURES / "sac_Pendulum-v1.zip", "Pendulum-v1", "SAC"),
    "dqn_FrozenLake-v1": (FIXTURES / "dqn_FrozenLake-v1.zip", "FrozenLake-v1", "DQN"),
}
ZOO = {
    "zoo_sac_MountainCarContinuous-v0": ("zoo/sac_MountainCarContinuous-v0/MountainCarContinuous-v0.zip", "MountainCarContinuous-v0", "SAC"),
    "zoo_tqc_Pendulum-v1": ("zoo/tqc_Pendulum-v1/Pendulum-v1.zip", "Pendulum-v1", "TQC"),
    "zoo_dqn_CartPole-v1": ("zoo/dqn_CartPole-v1/CartPole-v1.zip", "CartPole-v1", "DQN"),
    "zoo_qrdqn_CartPole-v1": ("zoo/qrdqn_CartPole-v1/CartPole-v1.zip", "CartPole-v1", "QR-DQN"),
    "ppo_CartPole-v1": ("sb3_ppo_cartpole/CartPole-v1.zip", "CartPole-v1", "PPO/A2C"),
}


def _env(env_id: str) -> gym.Env:
    return gym.make(env_id, is_slippery=False) if env_id == "FrozenLake-v1" else gym.make(env_id)


def _case(name: str, testdata: Path | None) -> tuple[Path, str, str]:
    if name in TRAINED:
        return TRAINED[name]
    if testdata is None:
        pytest.skip("../shared/testdata is absent (the zoo's zips live there)")
    relative, env_id, algorithm = ZOO[name]
    return testdata / "experts" / relative, env_id, algorithm


@pytest.fixture
def optional_testdata(request: pytest.FixtureRequest) -> Path | None:
    try:
        return request.getfixturevalue("testdata")
    except pytest.skip.Exception:
        return None


@pytest.mark.parametrize("name", [*TRAINED, *ZOO])
def test_actions_equal_sb3s_own(name: str, optional_testdata: Path | None) -> None:
    path, env_id, algorithm = _case(name, optional_testdata)
    reference = np.load(FIXTURES / f"{name}.reference.npz")
    expert, named = load_sb3_expert(path)
    assert named == algorithm
    ours = expert.predict(reference["observations"])
    theirs = reference["actions"]
    if np.issubdtype(theirs.dtype, np.integer):
        assert np.array_equal(ours.reshape(theirs.shape), theirs), name
    else:
        np.testing.assert_allclose(ours.reshape(theirs.shape), theirs, atol=1e-5, err_msg=name)


@pytest.mark.parametrize("name", ["td3_Pendulum-v1", "sac_Pendulum-v1", "zoo_sac_MountainCarContinuous-v0", "zoo_tqc_Pendulum-v1", "zoo_dqn_CartPole-v1"])
def test_the_experts_return_is_sb3s(name: str, optional_testdata: Path | None) -> None:
    """Over episodes seeded 0-9, the return SB3 measured for the same zip, within 10 %."""
    path, env_id, _ = _case(name, optional_testdata)
    sb3_return = float(np.load(FIXTURES / f"{name}.reference.npz")["returns"].mean())
    expert, _ = load_sb3_expert(path)
    env = _env(env_id)
    try:
        ours = evaluate_policy(SingleObservationPolicy(expert), env, episodes=10, seed=0)["mean_return"]
    finally:
        env.close()
    assert abs(ours - sb3_return) <= 0.1 * abs(sb3_return), (ours, sb3_return)


@pytest.mark.parametrize(
    ("name", "env_id"),
    [("td3_Pendulum-v1", "Pendulum-v1"), ("sac_Pendulum-v1", "Pendulum-v1"), ("zoo_dqn_CartPole-v1", "CartPole-v1")],
)
def test_record_and_dagger_with_the_expert(name: str, env_id: str, tmp_path: Path, optional_testdata: Path | None) -> None:
    path, _, _ = _case(name, optional_testdata)
    sb3_return = float(np.load(FIXTURES / f"{name}.reference.npz")["returns"][:3].mean())  # SB3's, on the same seeds 0-2
    record = last_json(run_cli("record", "--env", env_id, "--expert", f"sb3:{path}", "--episodes", "3", "--seed", "0", "--out", str(tmp_path / "demos.mcap"), "--quiet", "--json"))
    assert record["episodes"] == 3 and abs(record["mean_return"] - sb3_return) <= 0.1 * abs(sb3_return), record
    dagger = last_json(run_cli(
        "train", "dagger", "--env", env_id, "--expert", f"sb3:{path}", "--rounds", "2", "--episodes-per-round", "1", "--epochs", "3",
        "--out", str(tmp_path / "dagger"), "--quiet", "--json",
    ))
    assert dagger["rounds"] == 2 and dagger["expert_labels"] > 0 and (tmp_path / "dagger" / "rounds" / "round-02.mcap").is_file()


def test_an_expert_for_another_env_is_refused_naming_its_algorithm(tmp_path: Path) -> None:
    path = TRAINED["td3_Pendulum-v1"][0]
    result = run_cli("record", "--env", "CartPole-v1", "--expert", f"sb3:{path}", "--episodes", "1", "--out", str(tmp_path / "x.mcap"))
    assert_one_line_error(result, f"--expert sb3:{path} (TD3)", "observation space")


def test_load_sb3_policy_is_for_actor_critics() -> None:
    with pytest.raises(ImitationError, match=r"\(TD3\): not a PPO/A2C actor-critic"):
        load_sb3_policy(TRAINED["td3_Pendulum-v1"][0])
