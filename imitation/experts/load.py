"""Turn an `--expert` spec into a policy (observation → action) for an environment."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym

from imitation.envs.make import make_env
from imitation.envs.tabular import TabularEnv
from imitation.errors import ImitationError
from imitation.experts.sb3 import load_sb3_expert
from imitation.experts.scripted import scripted_expert
from imitation.experts.standin import StandIn
from imitation.experts.tabular import SoftOptimalExpert
from imitation.experts.window import ExpertWindow
from imitation.policies import SingleObservationPolicy, check_policy_fits_env
from imitation.policy_kinds import load_policy

Policy = Callable[[Any], Any]
EXPERT_SPECS = ("scripted", "random", "standin", "keyboard", "gamepad", "pointer", "RUN_DIR", "sb3:PATH")
PEOPLE = ("keyboard", "gamepad", "pointer")


def make_env_for_expert(env_id: str, spec: str, *, pixels: bool = False) -> gym.Env:
    """The env an expert acts in: rendered to frames when a human must see them or when they
    are recorded (`pixels`)."""
    return make_env(env_id, render_mode="rgb_array") if spec in PEOPLE or pixels else make_env(env_id)


def load_expert(spec: str, env: gym.Env, *, seed: int, speed: float = 1.0) -> Policy:
    """`scripted`: the hand-written controller for env's id (for a tabular MDP: its soft-optimal
    policy, see `imitation.experts.tabular`); `random`: uniform actions from the
    action space, seeded with `seed` so recordings are reproducible; a run directory: its saved
    policy (PPO, BC, DAgger), acting deterministically; `sb3:PATH`: the policy in a
    stable-baselines3 zip (PPO, A2C, SAC, TD3, TQC, DQN, QR-DQN), read without unpickling
    (see `imitation.experts.sb3`), acting deterministically; `standin`: a scripted person who
    takes the controls when the state turns risky (see `imitation.experts.standin`); `keyboard`,
    `gamepad`, `pointer`: a person (see `imitation.experts.keyboard`, `.gamepad` and `.pointer`; the
    env must come from `make_env_for_expert`), whose window runs at `speed` times real time."""
    if Path(spec).is_dir():
        policy = load_policy(spec)
        if policy.config.previous_action:
            raise ImitationError(
                f"--expert {spec}: the policy acts on the previous action as well as the state (BC on a command stream); "
                "an expert labels states alone: run it with eval policy"
            )
        check_policy_fits_env(policy, env, f"--expert {spec}")
        return SingleObservationPolicy(policy)
    if spec.startswith("sb3:"):
        expert, algorithm = load_sb3_expert(spec.removeprefix("sb3:"))
        check_policy_fits_env(expert, env, f"--expert {spec} ({algorithm})")
        return SingleObservationPolicy(expert)
    if spec == "scripted":
        if isinstance(env.unwrapped, TabularEnv):
            return SoftOptimalExpert(env, seed=seed)
        return scripted_expert(env.spec.id if env.spec else "")
    if spec == "keyboard":
        from imitation.experts.keyboard import KeyboardExpert  # pygame only when a human plays

        return KeyboardExpert(env, speed=speed)
    if spec == "gamepad":
        from imitation.experts.gamepad import GamepadExpert  # pygame only when a human plays

        return GamepadExpert(env, speed=speed)
    if spec == "pointer":
        from imitation.experts.pointer import PointerExpert  # pygame only when a human plays

        return PointerExpert(env, speed=speed)
    if spec == "standin":
        return StandIn(env.spec.id if env.spec else "")
    if spec == "random":
        action_space = env.action_space
        action_space.seed(seed)
        return lambda observation: action_space.sample()
    raise ImitationError(f"--expert {spec!r}: expected one of {', '.join(EXPERT_SPECS)}")


def close_expert(expert: Policy) -> None:
    """Close a person's window; the other experts hold nothing to close."""
    if isinstance(expert, ExpertWindow):
        expert.close()
