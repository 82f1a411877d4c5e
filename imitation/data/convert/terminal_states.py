"""Ending demos where the env's own termination rule first holds on their recorded states.

People who record demos by hand often keep stepping after the env would have ended the episode:
a MountainCar set whose every episode runs 130 rows, though the car reached the flag earlier.
Read as it is, every step past the goal costs −1, and a policy that stops at the goal is scored
above the demos.

The rule is the env's, never restated here: for each recorded transition (s_t, a_t, s_{t+1}),
the env's state is set to s_t and the env is stepped with a_t (on `env.unwrapped`, so that no
time limit or order check intervenes); the env says whether the state it reaches is terminal.
That state must be the recorded s_{t+1} (to within float32 rounding carried through one step):
otherwise the recorded states are not the env's, the rule would be applied to states the demos
never held, and the conversion is refused, naming the episode and step. This also catches a
layout that reads the rows wrongly (next states taken for states).

It needs an env whose state is its observation: `unwrapped.state`, of the observation's shape,
equal to the observation after a reset (gymnasium's CartPole, MountainCar, MountainCarContinuous).
Envs that observe something else than they keep (Pendulum observes cos θ, sin θ for its θ;
Acrobot likewise; MuJoCo envs leave out positions) are refused in one line.

Each episode is cut after the first transition into a terminal state and is then terminated; the
steps recorded after it are dropped and counted (`steps_cut` in each episode's metadata, the total
in `end_flags` and a warning). An episode that never reaches one is truncated: its last recorded
state is, by the env's rule, not terminal.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import gymnasium as gym
import numpy as np

from imitation.data.convert.converted import Converted
from imitation.data.convert.endings import TERMINAL_STATE
from imitation.data.types import Episode
from imitation.errors import ImitationError

# A recorded state is the env's when a step from the one before lands on it within these: float32
# rounding of the recorded state (about 1e-7 relative), carried through one step of the dynamics.
RTOL, ATOL = 1e-5, 1e-6


def end_at_terminal_states(converted: Converted, asked_by: str) -> Converted:
    """`converted` (fitted to its env) with each episode ended at its first terminal state by the
    env's own rule, its flags and `end_flags` saying so; `asked_by` names what asked for it, for
    messages."""
    env_id = converted.env_id
    if not env_id:
        raise ImitationError(
            f"{converted.source}: {asked_by} ends each episode where the env's termination rule first holds on its "
            "recorded states, and no --env was given; give --env ID"
        )
    from imitation.envs.make import make_env

    with make_env(env_id) as env:
        _check_state_is_observation(env, env_id, asked_by)
        episodes = [_cut(env, env_id, converted.source, k, episode) for k, episode in enumerate(converted.episodes)]
    cut = [episode for episode in episodes if episode.terminated]
    steps_cut = sum(int(episode.metadata["steps_cut"]) for episode in episodes)
    warnings = list(converted.warnings)
    never = len(episodes) - len(cut)
    warnings.append(
        f"{converted.source}: {len(cut)} of {len(episodes)} episodes reach a terminal state of {env_id}; the {steps_cut} "
        "steps recorded after it were cut (episode metadata steps_cut)"
        + (f", and the {never} that never reach one are truncated" if never else "")
    )
    limit = converted.max_episode_steps
    if limit is not None and (longer := sum(len(episode) > limit for episode in episodes)):
        warnings.append(
            f"{converted.source}: {longer} episode(s) run longer than {env_id}'s time limit of {limit} steps "
            "(the env would have truncated them there)"
        )
    end_flags: dict[str, Any] = {
        "decided": TERMINAL_STATE,
        "env_id": env_id,
        "steps_cut": steps_cut,
        "terminated": len(cut),
        "truncated": len(episodes) - len(cut),
    }
    return dataclasses.replace(converted, episodes=episodes, warnings=warnings, end_flags=end_flags, ends=None)


def _check_state_is_observation(env: gym.Env, env_id: str, asked_by: str) -> None:
    observation, _ = env.reset(seed=0)
    state = getattr(env.unwrapped, "state", None)
    if not isinstance(env.observation_space, gym.spaces.Box):
        detail = f"it observes a {type(env.observation_space).__name__}"
    elif state is None:
        detail = "it keeps no `state`"
    elif np.shape(state) != np.shape(observation):
        detail = f"its `state` has shape {list(np.shape(state))}, its observation {list(np.shape(observation))}"
    elif not np.array_equal(np.asarray(state).astype(observation.dtype), observation):
        detail = f"after a reset it keeps {_values(np.asarray(state))} and observes {_values(observation)}"
    else:
        return
    raise ImitationError(
        f"--env {env_id}: {asked_by} applies {env_id}'s termination rule to recorded states by setting its state to them, "
        f"and {env_id}'s observation is not its state ({detail}); state how its episodes ended instead (ends: "
        "time_limit, terminated or truncated)"
    )


def _cut(env: gym.Env, env_id: str, source: str, k: int, episode: Episode) -> Episode:
    """`episode` ended after its first transition into a terminal state, or truncated if none."""
    observations, actions = episode.observations, episode.actions
    assert isinstance(observations, np.ndarray) and isinstance(actions, np.ndarray)  # Box observations, checked above
    # A bare array's episodes hold observations, actions and rewards alone: nothing else to cut.
    assert episode.infos is None and episode.timestamps is None and episode.interventions is None
    env.reset(seed=0)  # clears what an env keeps between steps (CartPole's steps past a termination)
    unwrapped: Any = env.unwrapped  # its `state` is the env class's own attribute, found above
    state_dtype = np.asarray(unwrapped.state).dtype
    state_dtype = state_dtype if state_dtype.kind == "f" else np.dtype(np.float64)
    steps = len(actions)
    for t in range(steps):
        unwrapped.state = np.array(observations[t], dtype=state_dtype)
        action = int(actions[t]) if isinstance(env.action_space, gym.spaces.Discrete) else actions[t]
        reached, _, terminated, _, _ = unwrapped.step(action)
        recorded = observations[t + 1]
        if not np.allclose(np.asarray(reached, np.float64), np.asarray(recorded, np.float64), rtol=RTOL, atol=ATOL):
            raise ImitationError(
                f"{source}: episode {k}, step {t}: {env_id} steps from the recorded state {_values(observations[t])} with "
                f"action {_values(np.asarray(actions[t]))} to {_values(np.asarray(reached))}, not to the recorded "
                f"{_values(recorded)}: these are not {env_id}'s states (check the layout's rows and observation columns), "
                "so its termination rule cannot be applied to them"
            )
        if terminated:
            kept = t + 1
            return dataclasses.replace(
                episode,
                observations=observations[: kept + 1],
                actions=actions[:kept],
                rewards=np.asarray(episode.rewards)[:kept],
                terminated=True,
                truncated=False,
                metadata={**episode.metadata, "steps_cut": steps - kept},
            )
    return dataclasses.replace(episode, terminated=False, truncated=True, metadata={**episode.metadata, "steps_cut": 0})


def _values(array: np.ndarray) -> str:
    return "[" + ", ".join(f"{value:.6g}" for value in np.asarray(array, dtype=np.float64).reshape(-1)[:8]) + "]"
