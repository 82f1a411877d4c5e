"""Scripted experts: hand-written controllers for classic-control tasks, no learning involved.

These are the experts behind `imitation record --expert scripted`. Each is a deterministic
function of the observation alone, so it can label any state (for recording demonstrations or
as the DAgger oracle) and reproduces the same actions for the same states.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from imitation.errors import ImitationError

_CARTPOLE_GAINS = np.array([1.0, 1.0, 10.0, 2.0])

# Chosen by grid search, checked on 2000 other seeds; with the turn point below about -0.48
# some starts from rest push right first, fall short and need a third swing (-175).
_MOUNTAIN_CAR_SLOPE = 0.01
_MOUNTAIN_CAR_TURN = -0.47

# Pendulum: E = ½θ̇² + 15 cos θ is 15 exactly when the pendulum is upright and at rest.
_PENDULUM_TARGET_ENERGY = 15.0
_PENDULUM_PUMP_GAIN = 0.5
_PENDULUM_KP = 8.0
_PENDULUM_KD = 2.0
_PENDULUM_CATCH_ANGLE = 0.7
_PENDULUM_MAX_TORQUE = 2.0


def cartpole_score(obs: np.ndarray) -> float:
    """x + ẋ + 10θ + 2θ̇: the scripted CartPole expert's switching function; its sign is the action,
    its size how far the state is from the expert's indifference."""
    return float(_CARTPOLE_GAINS @ np.asarray(obs, dtype=np.float64)[:4])


def cartpole(obs: np.ndarray) -> int:
    """CartPole-v1: push right (1) iff x + ẋ + 10θ + 2θ̇ > 0, else left (0).

    The θ and θ̇ terms move the cart under the falling pole, which keeps it upright; the small
    x and ẋ terms tilt the pole slightly towards the centre so the cart drifts back instead of
    leaving |x| < 2.4 (it stays within about 0.15 of the centre). Extra observation entries
    (the failure flag of imitation/CartPoleFixedHorizon-v0) are ignored.
    """
    return int(cartpole_score(obs) > 0.0)


def mountain_car(obs: np.ndarray) -> int:
    """MountainCar-v0: push right (2) iff v > 0.01 (x + 0.47), else left (0).

    Pushing along the velocity pumps energy into the swing until the car clears the right hill;
    the slightly tilted switching line decides the first swing from rest (right of x = -0.47 it
    backs up the left slope first, for a longer run-up) and reverses a little early at the ends.
    """
    position, velocity = float(obs[0]), float(obs[1])
    return 2 if velocity > _MOUNTAIN_CAR_SLOPE * (position - _MOUNTAIN_CAR_TURN) else 0


def pendulum(obs: np.ndarray) -> np.ndarray:
    """Pendulum-v1: u = -8θ - 2θ̇ if |θ| < 0.7, else u = 0.5 (15 - E) θ̇, E = ½θ̇² + 15 cos θ.

    Away from the top, dE/dt = 3uθ̇ = 1.5 (15 - E) θ̇² drives the energy monotonically to that
    of the upright pendulum at rest; near the top the PD law turns θ̈ = 15θ + 3u into
    θ̈ = -9θ - 6θ̇, critically damped at 3 rad/s. u is clipped to the torque limit [-2, 2].
    """
    cos_theta, sin_theta, theta_dot = (float(v) for v in obs)
    theta = float(np.arctan2(sin_theta, cos_theta))
    if abs(theta) < _PENDULUM_CATCH_ANGLE:
        torque = -_PENDULUM_KP * theta - _PENDULUM_KD * theta_dot
    else:
        energy = 0.5 * theta_dot**2 + _PENDULUM_TARGET_ENERGY * cos_theta
        torque = _PENDULUM_PUMP_GAIN * (_PENDULUM_TARGET_ENERGY - energy) * theta_dot
    clipped = min(max(torque, -_PENDULUM_MAX_TORQUE), _PENDULUM_MAX_TORQUE)
    return np.array([clipped], dtype=np.float32)


SCRIPTED_EXPERTS: dict[str, Callable[[np.ndarray], Any]] = {
    "CartPole-v1": cartpole,
    "imitation/CartPoleFixedHorizon-v0": cartpole,
    "MountainCar-v0": mountain_car,
    "Pendulum-v1": pendulum,
}


def scripted_expert(env_id: str) -> Callable[[np.ndarray], Any]:
    """The scripted controller for `env_id`; ImitationError if there is none."""
    try:
        return SCRIPTED_EXPERTS[env_id]
    except KeyError:
        available = ", ".join(SCRIPTED_EXPERTS)
        raise ImitationError(f"no scripted expert for {env_id!r}; available: {available}") from None
