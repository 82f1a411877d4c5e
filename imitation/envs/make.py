"""Make gymnasium environments with one-line errors, and read their control period."""

from __future__ import annotations

from typing import Any

import gymnasium as gym

from imitation.errors import ImitationError


def make_env(env_id: str, **kwargs: Any) -> gym.Env:
    """`gymnasium.make(env_id)`, turning gymnasium's errors into a one-line ImitationError."""
    try:
        return gym.make(env_id, **kwargs)
    except gym.error.Error as error:
        raise ImitationError(f"environment {env_id!r}: {str(error).splitlines()[0]}") from None
    except ModuleNotFoundError as error:
        raise ImitationError(
            f"environment {env_id!r} needs the Python package {error.name!r}, which is not installed"
        ) from None


def control_period(env: gym.Env) -> float | None:
    """Seconds of simulated time per step, if the env says: MuJoCo and Pendulum have `dt`,
    CartPole `tau`; otherwise one frame of `render_fps`."""
    unwrapped = env.unwrapped
    for name in ("dt", "tau"):
        value = getattr(unwrapped, name, None)
        if isinstance(value, (int, float)) and value > 0:
            return float(value)
    fps = env.metadata.get("render_fps")
    return 1.0 / fps if fps else None
