"""Turn an `--expert` spec into a policy (observation → action) for an environment."""

from __future__ import annotations

from typing import Any, Callable

import gymnasium as gym

from imitation.errors import ImitationError
from imitation.experts.scripted import scripted_expert

Policy = Callable[[Any], Any]
EXPERT_SPECS = ("scripted", "random")


def load_expert(spec: str, env: gym.Env, *, seed: int) -> Policy:
    """`scripted`: the hand-written controller for env's id; `random`: uniform actions from the
    action space, seeded with `seed` so recordings are reproducible."""
    if spec == "scripted":
        return scripted_expert(env.spec.id if env.spec else "")
    if spec == "random":
        action_space = env.action_space
        action_space.seed(seed)
        return lambda observation: action_space.sample()
    raise ImitationError(f"--expert {spec!r}: expected one of {', '.join(EXPERT_SPECS)}")
