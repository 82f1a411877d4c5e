"""A human with a gamepad as the expert of a continuous-action environment (`--expert gamepad`).

The env is shown in the shared expert window (`imitation.experts.window`: heads-up strip, Esc,
pause, speed). Stick axis i steers action dimension i over its bounds: the action is
centre + value × half-range, value in [-1, 1], so a released stick commands the centre (for
Pendulum: no torque); dimensions without an axis stay at the centre. Deflections within the
dead zone count as zero, so a worn stick that rests slightly off centre neither steers nor
takes over. Without a gamepad the arrow keys stand in: left/right drive axis 0 to -1/+1 while
held, down/up axis 1. For take-over DAgger the person holds control (`engaged`) while a stick
is deflected, a button or an arrow key held. Inputs are tracked from events, so a test can
drive the expert by posting joystick events.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from imitation.errors import ImitationError
from imitation.experts.window import ExpertWindow, env_name


def gamepad_bounds(env: gym.Env) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) of env's action vector; ImitationError unless it is a 1-D Box with finite bounds."""
    space = env.action_space
    if not isinstance(space, gym.spaces.Box):
        raise ImitationError(
            f"--expert gamepad needs a continuous (Box) action space; {env_name(env)} has {type(space).__name__} actions"
        )
    if len(space.shape) != 1 or not (np.all(np.isfinite(space.low)) and np.all(np.isfinite(space.high))):
        raise ImitationError(
            f"--expert gamepad needs a 1-D action vector with finite bounds; {env_name(env)} has actions of shape "
            f"{space.shape} between {space.low.min()} and {space.high.max()}"
        )
    return space.low.astype(np.float64), space.high.astype(np.float64)


class GamepadExpert(ExpertWindow):
    """Shows the env in a window and returns the action the sticks command (see module doc)."""

    def __init__(self, env: gym.Env, *, fps: float | None = None, speed: float = 1.0, dead_zone: float = 0.15) -> None:
        self.low, self.high = gamepad_bounds(env)
        self.centre, self.half_range = (self.low + self.high) / 2, (self.high - self.low) / 2
        self._dtype = env.action_space.dtype
        self.dead_zone = dead_zone
        super().__init__(
            env, fps=fps, speed=speed, expert="gamepad", help_text="sticks or arrow keys steer; any button takes over"
        )
        pygame = self.pygame
        self._arrows = {pygame.K_LEFT: (0, -1.0), pygame.K_RIGHT: (0, 1.0), pygame.K_DOWN: (1, -1.0), pygame.K_UP: (1, 1.0)}
        self._held: list[int] = []  # arrow keys down, oldest first: the most recent one per axis wins
        self._axes: dict[tuple[int, int], float] = {}  # (joystick, axis) → value beyond the dead zone
        self._buttons: set[tuple[int, int]] = set()  # (joystick, button) held
        # Only an opened joystick sends events; those plugged in later arrive as JOYDEVICEADDED.
        pygame.joystick.init()
        self._joysticks: dict[int, Any] = {}
        for index in range(pygame.joystick.get_count()):
            self._open(index)

    def close(self) -> None:
        self._joysticks.clear()
        self.pygame.joystick.quit()
        super().close()

    def _open(self, index: int) -> None:
        try:
            joystick = self.pygame.joystick.Joystick(index)
        except self.pygame.error:  # unplugged again before it could be opened
            return
        self._joysticks[joystick.get_instance_id()] = joystick

    def _handle(self, event: Any) -> None:
        pygame = self.pygame
        if event.type == pygame.JOYAXISMOTION:
            value = float(event.value) if abs(event.value) > self.dead_zone else 0.0
            self._axes[(event.instance_id, event.axis)] = value
        elif event.type == pygame.JOYBUTTONDOWN:
            self._buttons.add((event.instance_id, event.button))
        elif event.type == pygame.JOYBUTTONUP:
            self._buttons.discard((event.instance_id, event.button))
        elif event.type == pygame.JOYDEVICEADDED:
            self._open(event.device_index)
        elif event.type == pygame.JOYDEVICEREMOVED:  # forget its inputs: they would stay stuck
            self._joysticks.pop(event.instance_id, None)
            self._axes = {key: value for key, value in self._axes.items() if key[0] != event.instance_id}
            self._buttons = {key for key in self._buttons if key[0] != event.instance_id}
        elif event.type == pygame.KEYDOWN and event.key in self._arrows and event.key not in self._held:
            self._held.append(event.key)
        elif event.type == pygame.KEYUP and event.key in self._held:
            self._held.remove(event.key)

    def _axis(self, axis: int) -> float:
        """Axis `axis` now: the most recent arrow key held for it, else the strongest stick deflection."""
        for key in reversed(self._held):
            key_axis, value = self._arrows[key]
            if key_axis == axis:
                return value
        return max((value for (_, a), value in self._axes.items() if a == axis), key=abs, default=0.0)

    def _engaged(self) -> bool:
        return bool(self._held or self._buttons or any(self._axes.values()))

    def _command(self) -> np.ndarray:
        values = np.array([self._axis(i) for i in range(len(self.centre))])
        return np.clip(self.centre + values * self.half_range, self.low, self.high).astype(self._dtype)
