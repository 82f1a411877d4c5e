"""The scripted experts solve their environments over a fixed set of seeds."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from imitation.errors import ImitationError
from imitation.evaluation.policy import evaluate_policy
from imitation.experts.scripted import SCRIPTED_EXPERTS, cartpole, cartpole_score, scripted_expert

SEEDS = range(20)


def _episode_returns(env_id: str) -> list[float]:
    env = gym.make(env_id)
    try:
        return evaluate_policy(scripted_expert(env_id), env, episodes=len(SEEDS), seed=SEEDS.start)["returns"]
    finally:
        env.close()


@pytest.mark.parametrize(
    ("env_id", "threshold"),
    [("CartPole-v1", 475.0), ("MountainCar-v0", -120.0), ("Pendulum-v1", -200.0)],
)
def test_scripted_expert_solves_env(env_id: str, threshold: float) -> None:
    returns = _episode_returns(env_id)
    assert np.mean(returns) >= threshold, f"{env_id}: returns {returns}"


def test_unknown_env_lists_available_experts() -> None:
    with pytest.raises(ImitationError) as excinfo:
        scripted_expert("Nope-v0")
    message = str(excinfo.value)
    assert "'Nope-v0'" in message
    for env_id in SCRIPTED_EXPERTS:
        assert env_id in message


def test_cartpole_score_is_the_switching_function() -> None:
    # x + ẋ + 10θ + 2θ̇ by hand; the fifth entry (the fixed-horizon failure flag) is ignored
    state = np.array([0.1, -0.2, 0.03, 0.5, 1.0])
    assert cartpole_score(state) == pytest.approx(0.1 - 0.2 + 0.3 + 1.0)
    assert cartpole(state) == 1
    assert cartpole(-state) == 0
