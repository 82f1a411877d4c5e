"""A human at the keyboard as the expert of a discrete-action environment (`--expert keyboard`).

The env is shown in the shared expert window (`imitation.experts.window`: heads-up strip, Esc,
pause, speed); every step the action is the one bound to the key held down (the most recent
when several are), or the env's no-op action when none is. For take-over DAgger, the person
holds control (`engaged`) while a bound key is held, or SPACE, which takes over with the no-op
action. Keys are tracked from key-down/key-up events rather than polled, so a test can drive
the expert by posting events.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym

from imitation.errors import ImitationError
from imitation.experts.window import ExpertWindow, env_name

# Per-env bindings (key name → action) and the action taken with no key held.
_BINDINGS: dict[str, tuple[dict[str, int], int]] = {
    "CartPole-v1": ({"left": 0, "right": 1}, 0),
    "MountainCar-v0": ({"left": 0, "right": 2}, 1),
    "Acrobot-v1": ({"left": 0, "right": 2}, 1),
    "LunarLander-v3": ({"right": 1, "up": 2, "left": 3}, 0),
}


def key_bindings(env: gym.Env) -> tuple[dict[str, int], int]:
    """(key name → action, no-op action) for env: known bindings, else digit keys 0-9."""
    if not isinstance(env.action_space, gym.spaces.Discrete):
        raise ImitationError(
            f"--expert keyboard needs a discrete action space; {env_name(env)} has {type(env.action_space).__name__} actions"
        )
    if env.spec is not None and env.spec.id in _BINDINGS:
        return _BINDINGS[env.spec.id]
    n = int(env.action_space.n)
    if n > 10:
        raise ImitationError(f"--expert keyboard has no key bindings for {n} actions (digit keys cover 10)")
    start = int(env.action_space.start)
    return {str(i): start + i for i in range(n)}, start


class KeyboardExpert(ExpertWindow):
    """Shows the env in a window and returns the action of the key held down (see module doc)."""

    def __init__(self, env: gym.Env, *, fps: float | None = None, speed: float = 1.0) -> None:
        bindings, self.noop = key_bindings(env)
        help_text = ", ".join(f"{name}={action}" for name, action in bindings.items())
        super().__init__(
            env, fps=fps, speed=speed, expert="keyboard", help_text=f"{help_text}; no key={self.noop}; SPACE takes over"
        )
        self._actions = {self.pygame.key.key_code(name): action for name, action in bindings.items()}
        self._held: list[int] = []  # keys down, oldest first: the most recent bound one wins

    def _handle(self, event: Any) -> None:
        if event.type == self.pygame.KEYDOWN and event.key not in self._held:
            self._held.append(event.key)
        elif event.type == self.pygame.KEYUP and event.key in self._held:
            self._held.remove(event.key)

    def _engaged(self) -> bool:
        return self.pygame.K_SPACE in self._held or any(key in self._actions for key in self._held)

    def _command(self) -> int:
        held = [key for key in self._held if key in self._actions]
        return self._actions[held[-1]] if held else self.noop
