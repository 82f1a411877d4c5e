"""A human at the keyboard as the expert of a discrete-action environment (`--expert keyboard`).

The environment is rendered (`render_mode="rgb_array"`) into a pygame window at the env's own
frame rate; every step the action is the one bound to the key held down, or the env's no-op
action when none is. Esc or closing the window stops the recording like Ctrl-C does: finished
episodes are kept. Keys are tracked from key-down/key-up events rather than polled, so a test
can drive the expert by posting events (with SDL_VIDEODRIVER=dummy).
"""

from __future__ import annotations

import os
import warnings
from typing import Any

import gymnasium as gym
import numpy as np

from imitation.errors import ImitationError

# Per-env bindings (key name → action) and the action taken with no key held.
_BINDINGS: dict[str, tuple[dict[str, int], int]] = {
    "CartPole-v1": ({"left": 0, "right": 1}, 0),
    "MountainCar-v0": ({"left": 0, "right": 2}, 1),
    "Acrobot-v1": ({"left": 0, "right": 2}, 1),
    "LunarLander-v3": ({"right": 1, "up": 2, "left": 3}, 0),
}


def _pygame() -> Any:
    os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # pygame's own import of the deprecated pkg_resources
        try:
            import pygame
        except ModuleNotFoundError:
            raise ImitationError("--expert keyboard needs pygame: pip install pygame") from None
    return pygame


def key_bindings(env: gym.Env) -> tuple[dict[str, int], int]:
    """(key name → action, no-op action) for env: known bindings, else digit keys 0-9."""
    if not isinstance(env.action_space, gym.spaces.Discrete):
        env_id = env.spec.id if env.spec else "this environment"
        raise ImitationError(
            f"--expert keyboard needs a discrete action space; {env_id} has {type(env.action_space).__name__} actions"
        )
    if env.spec is not None and env.spec.id in _BINDINGS:
        return _BINDINGS[env.spec.id]
    n = int(env.action_space.n)
    if n > 10:
        raise ImitationError(f"--expert keyboard has no key bindings for {n} actions (digit keys cover 10)")
    start = int(env.action_space.start)
    return {str(i): start + i for i in range(n)}, start


class KeyboardExpert:
    """Shows the env in a window and returns the action of the key held down (see module doc)."""

    def __init__(self, env: gym.Env, *, fps: float | None = None) -> None:
        if env.render_mode != "rgb_array":
            raise ImitationError("--expert keyboard needs the env made with render_mode='rgb_array'")
        self.env = env
        bindings, self.noop = key_bindings(env)
        self.pygame = _pygame()
        self.pygame.display.init()
        self._actions = {self.pygame.key.key_code(name): action for name, action in bindings.items()}
        self._held: list[int] = []
        self._screen = None
        self._clock = self.pygame.time.Clock()
        self.fps = fps or env.metadata.get("render_fps", 30)
        help_text = ", ".join(f"{name}={action}" for name, action in bindings.items())
        self.pygame.display.set_caption(f"{env.spec.id if env.spec else 'env'}: {help_text}; no key={self.noop}; Esc stops")

    def __call__(self, observation: Any) -> int:
        self._handle_events()
        frame = self.env.render()
        assert frame is None or isinstance(frame, np.ndarray)  # render_mode="rgb_array" (checked in __init__)
        self._show(frame)
        self._clock.tick(self.fps)
        held = [key for key in self._held if key in self._actions]
        return self._actions[held[-1]] if held else self.noop

    def close(self) -> None:
        self.pygame.display.quit()

    def _handle_events(self) -> None:
        pygame = self.pygame
        for event in pygame.event.get():
            if event.type == pygame.QUIT or (event.type == pygame.KEYDOWN and event.key == pygame.K_ESCAPE):
                raise KeyboardInterrupt
            if event.type == pygame.KEYDOWN and event.key not in self._held:
                self._held.append(event.key)  # the most recent key wins while several are held
            elif event.type == pygame.KEYUP and event.key in self._held:
                self._held.remove(event.key)

    def _show(self, frame: np.ndarray | None) -> None:
        if frame is None:
            return
        height, width = frame.shape[:2]
        if self._screen is None:
            self._screen = self.pygame.display.set_mode((width, height))
        self.pygame.surfarray.blit_array(self._screen, np.ascontiguousarray(frame.swapaxes(0, 1)))
        self.pygame.display.flip()
