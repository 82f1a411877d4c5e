"""The pygame window through which a person acts as the expert (`--expert keyboard`, `--expert gamepad`).

Each call shows the env's frame (`render_mode="rgb_array"`), scaled up so that small frames
stay visible, under a heads-up strip that says who is in control (the person or the learner,
as the DAgger loop reports through `show_status`), the round, episode, step, hand-overs so far,
the playback speed and whether the game is paused; then it waits out the frame at the env's
frame rate times `speed` and returns the person's current command. Keys every expert shares:
Esc (or closing the window) stops like Ctrl-C, `p` pauses and resumes, `-` and `=` (`+`) halve
and double the speed. Inputs are tracked from events rather than polled, so a test can drive
an expert by posting events.
"""

from __future__ import annotations

import math
import os
import warnings
from abc import ABC, abstractmethod
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from imitation.errors import ImitationError

MIN_WIDTH = 480  # frames narrower than this are scaled up by a whole factor, so pixels stay sharp
MIN_SPEED, MAX_SPEED = 1 / 8, 4.0
PAUSED_FPS = 10  # redraws a second while paused: enough to notice the keys, little CPU
_LINE_HEIGHTS = (30, 22, 20, 20)  # the strip's lines, in pixels: title, status, shared keys, the expert's keys
HUD_HEIGHT = sum(_LINE_HEIGHTS) + 8
_COLOURS = {"you": (20, 110, 40), "learner": (60, 60, 70), "paused": (150, 100, 0), "text": (255, 255, 255)}


@dataclass
class ControlStatus:
    """Where the DAgger loop stands, for the window's heads-up strip (see `ExpertWindow.show_status`)."""

    round: int  # DAgger round, 1-based
    episode: int  # episode within the round, 1-based
    step: int  # step within the episode
    human_in_control: bool
    interventions: int  # hand-overs to the person so far this round
    mode: str = "label"  # "label": the learner acts and the person labels; "takeover": the person may take over


def load_pygame(expert: str) -> Any:
    """The pygame module, imported only when a person plays; ImitationError naming `--expert
    EXPERT` when it is not installed."""
    os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # pygame's own import of the deprecated pkg_resources
        try:
            import pygame
        except ModuleNotFoundError:
            raise ImitationError(f"--expert {expert} needs pygame: pip install pygame") from None
    return pygame


def env_name(env: gym.Env) -> str:
    """The env's id for messages."""
    return env.spec.id if env.spec else "this environment"


class ExpertWindow(ABC):
    """A person acting through a pygame window (see module doc). Subclasses turn their device's
    events into a command: `_handle` tracks each event, `_command` is the action now and
    `_engaged` whether the person holds control now (a take-over)."""

    def __init__(self, env: gym.Env, *, fps: float | None, speed: float, expert: str, help_text: str) -> None:
        if env.render_mode != "rgb_array":
            raise ImitationError(f"--expert {expert} needs the env made with render_mode='rgb_array'")
        if not MIN_SPEED <= speed <= MAX_SPEED:
            raise ImitationError(f"--speed {speed:g}: must be between 1/8 and 4 (1 is real time)")
        self.env = env
        self.fps: float = fps or env.metadata.get("render_fps", 30)
        self.speed = speed
        self.paused = False
        self.engaged = False
        self.status: ControlStatus | None = None
        self.help_text = help_text
        self.pygame = load_pygame(expert)
        self.pygame.display.init()
        self.pygame.font.init()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # pygame's bundled font is found through the deprecated pkg_resources
            self._fonts = [self.pygame.font.Font(None, size) for size in (30, 21, 19, 19)]
        self._clock = self.pygame.time.Clock()
        self._frame: Any = None  # the last env frame, scaled: redrawn while paused
        self._screen: Any = None  # created at the first frame, when its size is known
        self.pygame.display.set_caption(f"{env_name(env)}: {help_text}; Esc stops")

    def __call__(self, observation: Any) -> Any:
        """Shows the env and returns the person's command; waits while paused."""
        self._handle_events()
        frame = self.env.render()
        assert frame is None or isinstance(frame, np.ndarray)  # render_mode="rgb_array" (checked in __init__)
        self._show(frame)
        self._clock.tick(self.fps * self.speed)
        while self.paused:
            self._handle_events()
            self._draw()
            self._clock.tick(PAUSED_FPS)
        self.engaged = self._engaged()
        return self._command()

    def show_status(self, status: ControlStatus) -> None:
        """Sets what the strip shows from the next call on."""
        self.status = status

    def hud_text(self) -> list[str]:
        """The strip's lines: who is in control (and PAUSED), the loop's status, the speed and the
        shared keys, the expert's own keys."""
        in_control = "YOU" if self.status is None or self.status.human_in_control else "learner"
        title = f"{in_control} in control" + ("   PAUSED (p resumes)" if self.paused else "")
        if self.status is None:
            where = ""
        else:
            s = self.status
            where = f"round {s.round} · episode {s.episode} · step {s.step} · interventions {s.interventions} · mode {s.mode}"
        keys = f"speed {self.speed:g}×   p pause · -/= speed · Esc stop"
        return [title, where, keys, self.help_text]

    def screenshot(self, path: str | Path) -> None:
        """Saves the window as it shows now (frame and strip) as a PNG."""
        if self._screen is None:
            raise RuntimeError("screenshot: the window opens at the expert's first call")
        self.pygame.image.save(self._screen, str(path))

    def close(self) -> None:
        self.pygame.display.quit()
        self._screen = None

    @abstractmethod
    def _handle(self, event: Any) -> None:
        """Track one pygame event (those of every kind, the shared keys included)."""

    @abstractmethod
    def _engaged(self) -> bool:
        """Whether the person holds control now."""

    @abstractmethod
    def _command(self) -> Any:
        """The action the person commands now."""

    def _handle_events(self) -> None:
        pygame = self.pygame
        for event in pygame.event.get():
            if event.type == pygame.QUIT or (event.type == pygame.KEYDOWN and event.key == pygame.K_ESCAPE):
                raise KeyboardInterrupt
            if event.type == pygame.KEYDOWN:
                if event.key == pygame.K_p:
                    self.paused = not self.paused
                elif event.key in (pygame.K_MINUS, pygame.K_KP_MINUS):
                    self.speed = max(MIN_SPEED, self.speed / 2)
                elif event.key in (pygame.K_EQUALS, pygame.K_PLUS, pygame.K_KP_PLUS):
                    self.speed = min(MAX_SPEED, self.speed * 2)
            self._handle(event)

    def _show(self, frame: np.ndarray | None) -> None:
        if frame is not None:  # None: an env that has nothing to show yet; keep the last frame
            surface = self.pygame.surfarray.make_surface(np.ascontiguousarray(frame.swapaxes(0, 1)))
            scale = math.ceil(MIN_WIDTH / surface.get_width())
            if scale > 1:
                surface = self.pygame.transform.scale(surface, (surface.get_width() * scale, surface.get_height() * scale))
            self._frame = surface
        self._draw()

    def _draw(self) -> None:
        if self._frame is None:
            return
        width, height = self._frame.get_width(), self._frame.get_height() + HUD_HEIGHT
        if self._screen is None or self._screen.get_size() != (width, height):
            self._screen = self.pygame.display.set_mode((width, height))
        self._screen.blit(self._frame, (0, HUD_HEIGHT))
        self._draw_hud(width)
        self.pygame.display.flip()

    def _draw_hud(self, width: int) -> None:
        human = self.status is None or self.status.human_in_control
        colour = _COLOURS["paused" if self.paused else "you" if human else "learner"]
        self._screen.fill(colour, (0, 0, width, HUD_HEIGHT))
        y = 4
        for line, font, height in zip(self.hud_text(), self._fonts, _LINE_HEIGHTS):
            self._screen.blit(font.render(line, True, _COLOURS["text"]), (8, y))
            y += height
