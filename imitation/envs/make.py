"""Make gymnasium environments with one-line errors, and read their control period."""

from __future__ import annotations

import importlib
import importlib.util
import warnings
from typing import Any

import gymnasium as gym

from imitation.errors import ImitationError


def make_env(env_id: str, **kwargs: Any) -> gym.Env:
    """`gymnasium.make(env_id)`, turning gymnasium's errors into a one-line ImitationError."""
    try:
        _import_namespace(env_id)
        spec = gym.registry.get(env_id)  # None for "module:id", which gym.make imports first
        if spec is not None and "mujoco" in str(spec.entry_point):
            _route_mujoco_warnings()
        return gym.make(env_id, **kwargs)
    except gym.error.Error as error:
        raise ImitationError(f"environment {env_id!r}: {str(error).splitlines()[0]}") from None
    except ModuleNotFoundError as error:
        raise ImitationError(
            f"environment {env_id!r} needs the Python package {error.name!r}, which is not installed"
        ) from None


def _import_namespace(env_id: str) -> None:
    """Register the envs of an id's namespace that an installed package of that name provides
    (`gym_pusht/PushT-v0` → `import gym_pusht`), as `gymnasium.make("module:id")` would: gymnasium
    finds a namespace only once its package registered it."""
    namespace = env_id.rpartition("/")[0]
    if not namespace or ":" in env_id or gym.registry.get(env_id) is not None or not namespace.isidentifier():
        return
    if importlib.util.find_spec(namespace) is not None:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="pkg_resources is deprecated")  # raised by importing pygame; harmless
            importlib.import_module(namespace)


def _route_mujoco_warnings() -> None:
    """MuJoCo writes its warnings to stderr and appends them to MUJOCO_LOG.TXT in the working
    directory. gymnasium's HalfCheetah model uses a compiler attribute that MuJoCo 3.3 and later
    deprecate, so every HalfCheetah made would print a line and leave that file behind in the
    user's folder. Deprecation notices about gymnasium's own models are dropped; every other
    MuJoCo warning (an unstable simulation, say) becomes a Python warning."""
    import mujoco

    def warn(text: str) -> None:
        if "deprecated" not in text:
            warnings.warn(f"MuJoCo: {text}", RuntimeWarning, stacklevel=2)

    mujoco.set_mju_user_warning(warn)


def control_period(env: gym.Env) -> float | None:
    """Seconds of simulated time per step, if the env says: an env that states its control rate
    (`control_hz`, as gym-pusht's PushT, whose `dt` is a physics substep) by it; MuJoCo and
    Pendulum have `dt`, CartPole `tau`; otherwise one frame of `render_fps`."""
    unwrapped = env.unwrapped
    control_hz = getattr(unwrapped, "control_hz", None)
    if isinstance(control_hz, (int, float)) and control_hz > 0:
        return 1.0 / control_hz
    for name in ("dt", "tau"):
        value = getattr(unwrapped, name, None)
        if isinstance(value, (int, float)) and value > 0:
            return float(value)
    fps = env.metadata.get("render_fps")
    return 1.0 / fps if fps else None
