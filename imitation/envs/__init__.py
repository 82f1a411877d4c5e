"""Environment construction and the project's own environments, registered with gymnasium on
import (as `imitation/<Name>-v0`) so that `record`, `train` and `eval` can name them."""

from typing import Any

from gymnasium.envs.registration import register, registry

from imitation.envs.fixed_horizon import CARTPOLE_HORIZON, MUJOCO_FIXED_HORIZON

_TABULAR = "imitation.envs.tabular:make_tabular_env"
_ENVS: dict[str, dict[str, Any]] = {
    "imitation/GridWorld8x8-v0": dict(entry_point=_TABULAR, kwargs={"world": "gridworld"}),
    "imitation/GridWorld8x8Slippery-v0": dict(entry_point=_TABULAR, kwargs={"world": "gridworld", "slip": 0.2}),
    "imitation/CliffWorld-v0": dict(entry_point=_TABULAR, kwargs={"world": "cliff_world"}),
    "imitation/RandomMDP-v0": dict(entry_point=_TABULAR, kwargs={"world": "random_mdp"}),
    "imitation/CartPoleFixedHorizon-v0": dict(
        entry_point="imitation.envs.fixed_horizon:CartPoleFixedHorizon", max_episode_steps=CARTPOLE_HORIZON
    ),
    **MUJOCO_FIXED_HORIZON,
}

for env_id, spec in _ENVS.items():
    if env_id not in registry:
        register(id=env_id, **spec)
