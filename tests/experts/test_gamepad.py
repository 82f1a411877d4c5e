"""The gamepad expert, driven by posted joystick and key events in a virtual X display (tests/xvfb.py)."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import gymnasium as gym
import numpy as np
import pytest
from xvfb import xvfb  # noqa: F401 (the fixture)

from imitation.errors import ImitationError
from imitation.experts.gamepad import GamepadExpert
from imitation.experts.window import HUD_HEIGHT

pygame = pytest.importorskip("pygame")
on_xvfb = pytest.mark.usefixtures("xvfb")


def stick(axis: int, value: float, joystick: int = 0) -> None:
    pygame.event.post(pygame.event.Event(pygame.JOYAXISMOTION, joy=joystick, instance_id=joystick, axis=axis, value=value))


def button(number: int, down: bool = True) -> None:
    kind = pygame.JOYBUTTONDOWN if down else pygame.JOYBUTTONUP
    pygame.event.post(pygame.event.Event(kind, joy=0, instance_id=0, button=number))


def press(key: int, down: bool = True) -> None:
    pygame.event.post(pygame.event.Event(pygame.KEYDOWN if down else pygame.KEYUP, key=key))


@contextmanager
def opened(env: gym.Env) -> Iterator[tuple[GamepadExpert, object]]:
    """A gamepad expert on env, freshly reset, and the first observation; closed afterwards."""
    observation, _ = env.reset(seed=0)
    expert = GamepadExpert(env, fps=1000)
    try:
        yield expert, observation
    finally:
        expert.close()


def pendulum() -> gym.Env:
    return gym.make("Pendulum-v1", render_mode="rgb_array")


@on_xvfb
def test_the_stick_steers_the_torque_over_its_range() -> None:
    with opened(pendulum()) as (expert, observation):
        action = expert(observation)
        assert action.shape == (1,) and action.dtype == np.float32
        assert action[0] == 0 and not expert.engaged  # released: no torque
        stick(0, 0.8)
        assert expert(observation)[0] == pytest.approx(1.6) and expert.engaged
        stick(0, -1.0)
        assert expert(observation)[0] == -2
        stick(0, 0.1)  # inside the dead zone
        assert expert(observation)[0] == 0 and not expert.engaged
        stick(1, 0.5)  # Pendulum has no second dimension: no torque, yet the person has taken over
        assert expert(observation)[0] == 0 and expert.engaged
        stick(1, 0.0)
        button(3)
        assert expert(observation)[0] == 0 and expert.engaged
        button(3, down=False)
        assert expert(observation)[0] == 0 and not expert.engaged
        assert pygame.display.get_surface().get_size() == (500, 500 + HUD_HEIGHT)


@on_xvfb
def test_arrow_keys_stand_in_for_the_stick() -> None:
    with opened(pendulum()) as (expert, observation):
        stick(0, 0.5)
        press(pygame.K_LEFT)
        assert expert(observation)[0] == -2 and expert.engaged  # the key wins over the stick
        press(pygame.K_RIGHT)
        assert expert(observation)[0] == 2  # the most recent key wins
        press(pygame.K_RIGHT, down=False)
        press(pygame.K_LEFT, down=False)
        assert expert(observation)[0] == 1  # back to the stick
        stick(0, 0.0)
        assert expert(observation)[0] == 0 and not expert.engaged


@on_xvfb
def test_axes_map_onto_dimensions_between_their_bounds() -> None:
    env = pendulum()
    env.action_space = gym.spaces.Box(np.array([-1.0, 0.0, 10.0]), np.array([1.0, 4.0, 20.0]), dtype=np.float64)
    with opened(env) as (expert, observation):
        np.testing.assert_allclose(expert(observation), [0, 2, 15])  # centres
        stick(1, -0.5)
        stick(2, 1.0)
        stick(0, 0.3, joystick=1)  # a second pad steers too
        action = expert(observation)
        assert action.dtype == np.float64
        np.testing.assert_allclose(action, [0.3, 1, 20])
        press(pygame.K_UP)
        np.testing.assert_allclose(expert(observation), [0.3, 4, 20])


@on_xvfb
def test_an_unplugged_pad_stops_steering() -> None:
    with opened(pendulum()) as (expert, observation):
        stick(0, -0.6, joystick=4)
        button(1)
        assert expert(observation)[0] == pytest.approx(-1.2) and expert.engaged
        pygame.event.post(pygame.event.Event(pygame.JOYDEVICEREMOVED, instance_id=4))
        assert expert(observation)[0] == pytest.approx(0) and expert.engaged  # button 1 was on pad 0
        pygame.event.post(pygame.event.Event(pygame.JOYDEVICEREMOVED, instance_id=0))
        assert not (expert(observation)[0] or expert.engaged)


@on_xvfb
def test_escape_stops_like_ctrl_c() -> None:
    with opened(pendulum()) as (expert, observation):
        press(pygame.K_ESCAPE)
        with pytest.raises(KeyboardInterrupt):
            expert(observation)


@on_xvfb
def test_the_screenshot_shows_the_pendulum_under_the_strip(tmp_path) -> None:
    with opened(pendulum()) as (expert, observation):
        expert(observation)
        expert.screenshot(tmp_path / "pad.png")
    image = pygame.image.load(str(tmp_path / "pad.png"))
    assert image.get_size() == (500, 500 + HUD_HEIGHT)
    assert image.get_at((2, 2))[:3] == (20, 110, 40)


@pytest.mark.parametrize(
    ("space", "message"),
    [
        (None, "^--expert gamepad needs a continuous \\(Box\\) action space; CartPole-v1 has Discrete actions$"),
        (
            gym.spaces.Box(-1, 1, (2, 2)),
            "^--expert gamepad needs a 1-D action vector with finite bounds; .* has actions of shape \\(2, 2\\)",
        ),
        (
            gym.spaces.Box(-np.inf, 1, (2,)),
            "^--expert gamepad needs a 1-D action vector with finite bounds; .* between -inf and 1.0$",
        ),
    ],
)
def test_other_action_spaces_are_refused(space: gym.spaces.Space | None, message: str) -> None:
    env = gym.make("CartPole-v1", render_mode="rgb_array")
    if space is not None:
        env.action_space = space
    with pytest.raises(ImitationError, match=message):
        GamepadExpert(env)
