"""PPOConfig's frame-stack bound, in process, at both edges (imitation/algorithms/ppo_config.py)."""

from __future__ import annotations

import pytest

from imitation.algorithms.ppo_config import PPOConfig
from imitation.errors import ConfigError


@pytest.mark.parametrize("frames", [1, 64])
def test_a_frame_stack_from_1_to_64_is_taken(frames: int) -> None:
    PPOConfig(env_id="CartPole-v1", frame_stack=frames).validate()


@pytest.mark.parametrize("frames", [0, 65])
def test_a_frame_stack_outside_1_to_64_is_refused_naming_it(frames: int) -> None:
    with pytest.raises(ConfigError) as refused:
        PPOConfig(env_id="CartPole-v1", frame_stack=frames).validate()
    assert str(refused.value) == f"frame_stack must be in [1, 64], got {frames}" and refused.value.owner == "PPOConfig"
