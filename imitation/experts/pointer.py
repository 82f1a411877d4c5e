"""A human with a mouse as the expert of an env whose action is a point of its picture
(`--expert pointer`): PushT's target position for the agent, a reacher's goal, a cursor.

The env is shown in the shared expert window (`imitation.experts.window`: heads-up strip, Esc,
pause, speed). The action is a Box of two numbers with finite bounds, and the pointer's place over
the env's frame maps onto it linearly: the frame's left edge is action 0's low bound and its right
edge the high one, the top edge action 1's low bound and the bottom the high one (image rows grow
downwards, as PushT's coordinates do). Until the pointer first moves over the frame the command is
the centre of the bounds. For take-over DAgger the person holds control (`engaged`) while a mouse
button is held, so moving the pointer to where the agent should go does not yet take over.
Inputs are tracked from events, so a test can drive the expert by posting mouse events.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from imitation.errors import ImitationError
from imitation.experts.window import HUD_HEIGHT, ExpertWindow, env_name


def pointer_bounds(env: gym.Env) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) of env's action; ImitationError unless it is a Box of two numbers with finite bounds."""
    space = env.action_space
    if not isinstance(space, gym.spaces.Box) or space.shape != (2,):
        shape = space.shape if isinstance(space, gym.spaces.Box) else type(space).__name__
        raise ImitationError(
            f"--expert pointer needs actions that are a point (a Box of 2 numbers); {env_name(env)} has {shape}"
        )
    if not (np.all(np.isfinite(space.low)) and np.all(np.isfinite(space.high))):
        raise ImitationError(f"--expert pointer needs finite action bounds to map the frame onto; {env_name(env)}'s are not")
    return space.low.astype(np.float64), space.high.astype(np.float64)


class PointerExpert(ExpertWindow):
    """Shows the env in a window and returns the point the mouse is over (see module doc)."""

    def __init__(self, env: gym.Env, *, fps: float | None = None, speed: float = 1.0) -> None:
        self.low, self.high = pointer_bounds(env)
        self._dtype = env.action_space.dtype
        self._point = (self.low + self.high) / 2
        self._buttons: set[int] = set()
        super().__init__(env, fps=fps, speed=speed, expert="pointer", help_text="the mouse points; hold a button to take over")

    def _handle(self, event: Any) -> None:
        pygame = self.pygame
        if event.type == pygame.MOUSEMOTION:
            self._aim(event.pos)
        elif event.type == pygame.MOUSEBUTTONDOWN:
            self._buttons.add(event.button)
            self._aim(event.pos)
        elif event.type == pygame.MOUSEBUTTONUP:
            self._buttons.discard(event.button)

    def _aim(self, position: tuple[int, int]) -> None:
        """Point at window pixel `position` (the frame is drawn below the strip), clipped to the frame."""
        if self._frame is None:
            return
        x, y = position
        fractions = np.array([x / self._frame.get_width(), (y - HUD_HEIGHT) / self._frame.get_height()])
        self._point = self.low + np.clip(fractions, 0.0, 1.0) * (self.high - self.low)

    def _engaged(self) -> bool:
        return bool(self._buttons)

    def _command(self) -> np.ndarray:
        return self._point.astype(self._dtype)
