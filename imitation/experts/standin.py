"""A programmable stand-in for a person at the controls (`--expert standin`).

It watches one quantity of the observation and takes the controls when its magnitude passes
`engage`, drives with the env's scripted controller while engaged, and hands them back once
the magnitude falls below `release` (hysteresis, as a person would: step in when the pole
leans, step out when it is upright again). As a labeller (`--mode label`) it is the scripted
controller. It lets the take-over loop of DAgger be tested and benchmarked without a person.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from imitation.errors import ImitationError
from imitation.experts.scripted import scripted_expert


@dataclass(frozen=True)
class Trigger:
    """The watched quantity of an observation and the thresholds on its magnitude."""

    quantity: Callable[[np.ndarray], float]
    engage: float
    release: float


def _pole_angle(observation: np.ndarray) -> float:
    return float(observation[2])


# CartPole: the pole angle θ (rad); it fails at |θ| > 0.21.
TRIGGERS = {
    "CartPole-v1": Trigger(_pole_angle, 0.1, 0.02),
    "imitation/CartPoleFixedHorizon-v0": Trigger(_pole_angle, 0.1, 0.02),
}


class StandIn:
    """A scripted person: `engaged` after each call says whether it holds the controls."""

    def __init__(self, env_id: str, *, engage: float | None = None, release: float | None = None) -> None:
        if env_id not in TRIGGERS:
            raise ImitationError(
                f"--expert standin has no take-over condition for {env_id}; it knows {', '.join(sorted(TRIGGERS))}"
            )
        trigger = TRIGGERS[env_id]
        self.engage = trigger.engage if engage is None else engage
        self.release = trigger.release if release is None else release
        if not 0 <= self.release <= self.engage:
            raise ImitationError(
                f"--expert standin: the release threshold {self.release} must lie in [0, engage = {self.engage}]"
            )
        self._quantity = trigger.quantity
        self._drive = scripted_expert(env_id)
        self.engaged = False

    def __call__(self, observation: Any) -> Any:
        magnitude = abs(self._quantity(np.asarray(observation)))
        self.engaged = magnitude >= self.release if self.engaged else magnitude > self.engage
        return self._drive(observation)
