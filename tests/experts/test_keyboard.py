"""The keyboard expert and the window it shares with the gamepad expert, driven by posted events
in a virtual X display (tests/xvfb.py)."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager

import gymnasium as gym
import pytest
from support import run_cli
from test_cli import assert_one_line_error
from xvfb import running_xvfb, xvfb, xvfb_env  # noqa: F401 (xvfb: the fixture)

from imitation.errors import ImitationError
from imitation.experts.keyboard import KeyboardExpert, key_bindings
from imitation.experts.window import HUD_HEIGHT, ControlStatus

pygame = pytest.importorskip("pygame")
on_xvfb = pytest.mark.usefixtures("xvfb")


def press(key: int, down: bool = True) -> None:
    pygame.event.post(pygame.event.Event(pygame.KEYDOWN if down else pygame.KEYUP, key=key))


@contextmanager
def opened(env_id: str, **kwargs) -> Iterator[tuple[KeyboardExpert, object]]:
    """A keyboard expert on a freshly reset env, and the first observation; closed afterwards."""
    env = gym.make(env_id, render_mode="rgb_array")
    observation, _ = env.reset(seed=0)
    expert = KeyboardExpert(env, **({"fps": 1000} | kwargs))
    try:
        yield expert, observation
    finally:
        expert.close()


@contextmanager
def watchdog(seconds: float = 10) -> Iterator[None]:
    """Closes the window (KeyboardInterrupt) after `seconds`: a pause that never ends fails the
    test instead of hanging it."""
    pygame.time.set_timer(pygame.event.Event(pygame.QUIT), int(seconds * 1000), loops=1)
    try:
        yield
    finally:
        pygame.time.set_timer(pygame.QUIT, 0)


@on_xvfb
def test_held_keys_choose_actions_and_no_key_is_noop() -> None:
    with opened("CartPole-v1") as (expert, observation):
        assert expert(observation) == 0  # no key: CartPole's no-op is "push left"
        press(pygame.K_RIGHT)
        assert expert(observation) == 1
        assert expert(observation) == 1  # still held
        press(pygame.K_LEFT)
        assert expert(observation) == 0  # the most recent key wins
        press(pygame.K_LEFT, down=False)
        assert expert(observation) == 1
        press(pygame.K_RIGHT, down=False)
        assert expert(observation) == 0
        width, height = expert.env.render().shape[1::-1]
        assert pygame.display.get_surface().get_size() == (width, height + HUD_HEIGHT)


@on_xvfb
def test_bound_keys_and_space_engage_the_person() -> None:
    with opened("MountainCar-v0") as (expert, observation):
        assert expert(observation) == 1 and not expert.engaged
        press(pygame.K_a)  # not bound: the learner keeps control
        assert expert(observation) == 1 and not expert.engaged
        press(pygame.K_LEFT)
        assert expert(observation) == 0 and expert.engaged
        press(pygame.K_LEFT, down=False)
        assert expert(observation) == 1 and not expert.engaged
        press(pygame.K_SPACE)  # take over with the no-op
        assert expert(observation) == 1 and expert.engaged
        press(pygame.K_SPACE, down=False)
        assert expert(observation) == 1 and not expert.engaged


@on_xvfb
def test_escape_and_closing_the_window_stop_like_ctrl_c() -> None:
    with opened("MountainCar-v0") as (expert, observation):
        assert expert(observation) == 1  # MountainCar's no-op
        press(pygame.K_ESCAPE)
        with pytest.raises(KeyboardInterrupt):
            expert(observation)
        pygame.event.post(pygame.event.Event(pygame.QUIT))
        with pytest.raises(KeyboardInterrupt):
            expert(observation)


@on_xvfb
def test_pause_waits_for_p_and_keeps_tracking_keys() -> None:
    with opened("CartPole-v1") as (expert, observation), watchdog():
        press(pygame.K_RIGHT)
        assert expert(observation) == 1
        press(pygame.K_p)
        pygame.time.set_timer(pygame.event.Event(pygame.KEYUP, key=pygame.K_RIGHT), 100, loops=1)
        pygame.time.set_timer(pygame.event.Event(pygame.KEYDOWN, key=pygame.K_p), 400, loops=1)
        start = time.monotonic()
        assert expert(observation) == 0  # right was released during the pause
        assert time.monotonic() - start >= 0.35 and not expert.paused


@on_xvfb
def test_escape_stops_a_paused_expert() -> None:
    with opened("CartPole-v1") as (expert, observation), watchdog():
        press(pygame.K_p)
        pygame.time.set_timer(pygame.event.Event(pygame.KEYDOWN, key=pygame.K_ESCAPE), 200, loops=1)
        with pytest.raises(KeyboardInterrupt):
            expert(observation)
        assert expert.paused and "PAUSED" in expert.hud_text()[0]


@on_xvfb
def test_speed_keys_scale_the_frame_rate_within_bounds() -> None:
    with opened("CartPole-v1", fps=100) as (expert, observation):
        for key in (pygame.K_EQUALS, pygame.K_EQUALS, pygame.K_EQUALS):
            press(key)
        expert(observation)
        assert expert.speed == 4  # doubled twice, then held at the top
        for _ in range(8):
            press(pygame.K_MINUS)
        expert(observation)
        assert expert.speed == 1 / 8 and "speed 0.125×" in expert.hud_text()[2]
        press(pygame.K_PLUS)
        press(pygame.K_PLUS)
        press(pygame.K_PLUS)  # 1/8 → 1
        expert(observation)
        press(pygame.K_MINUS)
        press(pygame.K_MINUS)  # 1 → 1/4: 25 frames a second instead of 100
        expert(observation)
        start = time.monotonic()
        for _ in range(5):
            expert(observation)
        assert time.monotonic() - start >= 5 / 25 * 0.9


def test_speed_out_of_range_is_refused() -> None:
    env = gym.make("CartPole-v1", render_mode="rgb_array")
    with pytest.raises(ImitationError, match=r"^--speed 8: must be between 1/8 and 4 \(1 is real time\)$"):
        KeyboardExpert(env, speed=8)


def test_an_env_without_frames_is_refused() -> None:
    with pytest.raises(ImitationError, match="^--expert keyboard needs the env made with render_mode='rgb_array'$"):
        KeyboardExpert(gym.make("CartPole-v1"))


@on_xvfb
def test_the_strip_shows_the_status_and_the_screenshot_the_window(tmp_path) -> None:
    with opened("CartPole-v1") as (expert, observation):
        expert(observation)
        expert.screenshot(tmp_path / "you.png")
        expert.show_status(ControlStatus(round=2, episode=3, step=4, human_in_control=False, interventions=1, mode="takeover"))
        assert expert.hud_text()[:2] == [
            "learner in control",
            "round 2 · episode 3 · step 4 · interventions 1 · mode takeover",
        ]
        expert(observation)
        expert.screenshot(tmp_path / "learner.png")
    you, learner = (pygame.image.load(str(tmp_path / name)) for name in ("you.png", "learner.png"))
    assert you.get_size() == learner.get_size() == (600, 400 + HUD_HEIGHT)
    assert you.get_at((2, 2))[:3] == (20, 110, 40) and learner.get_at((2, 2))[:3] == (60, 60, 70)  # green: the person drives
    strip = pygame.surfarray.array3d(learner)[:, :HUD_HEIGHT]
    assert (strip == 255).all(axis=2).sum() > 500  # the text is drawn (white)
    assert pygame.surfarray.array3d(learner)[:, HUD_HEIGHT:].mean() > 200  # CartPole's white background below it


@on_xvfb
def test_small_frames_are_scaled_up() -> None:
    with opened("FrozenLake-v1") as (expert, observation):  # 256 × 256 frames, digit keys
        assert expert(observation) == 0
        press(pygame.K_2)
        assert expert(observation) == 2
        assert pygame.display.get_surface().get_size() == (512, 512 + HUD_HEIGHT)


def test_bindings_for_unknown_discrete_envs_use_digits() -> None:
    gym.register("TestThreeActions-v0", entry_point="gymnasium.envs.classic_control.cartpole:CartPoleEnv")
    env = gym.make("TestThreeActions-v0")
    env.action_space = gym.spaces.Discrete(3)
    assert key_bindings(env) == ({"0": 0, "1": 1, "2": 2}, 0)


def test_continuous_envs_are_refused(tmp_path) -> None:
    with pytest.raises(ImitationError, match="needs a discrete action space; Pendulum-v1 has Box actions"):
        key_bindings(gym.make("Pendulum-v1"))
    result = run_cli(
        "record",
        "--env",
        "Pendulum-v1",
        "--expert",
        "keyboard",
        "--out",
        str(tmp_path / "x.mcap"),
        env={**os.environ, "SDL_VIDEODRIVER": "dummy"},
    )
    assert_one_line_error(result, "discrete action space")
    assert list(tmp_path.iterdir()) == []


@on_xvfb
def test_a_keyboard_episode_is_recorded(tmp_path) -> None:
    from imitation.data.mcap.reader import DemoFile
    from imitation.data.mcap.writer import DemoWriter
    from imitation.data.recorder import RecordEpisodes, run_episodes

    env = gym.make("CartPole-v1", render_mode="rgb_array")
    expert = KeyboardExpert(env, fps=1000)
    press(pygame.K_RIGHT)  # held for the whole episode: the pole falls within a few dozen steps
    try:
        with DemoWriter(
            tmp_path / "human.mcap",
            env_id="CartPole-v1",
            observation_space=env.observation_space,
            action_space=env.action_space,
        ) as writer:
            run_episodes(RecordEpisodes(env, writer), expert, episodes=1, seed=0, progress=False)
    finally:
        expert.close()
    episode = DemoFile(tmp_path / "human.mcap")[0]
    assert episode.terminated and len(episode) < 100 and set(episode.actions.tolist()) == {1}


def test_a_subprocess_draws_on_the_virtual_display() -> None:
    script = "import pygame; pygame.display.init(); pygame.display.set_mode((64, 64)); print(pygame.display.get_driver())"
    with running_xvfb() as display:
        result = subprocess.run(
            [sys.executable, "-c", script], env=xvfb_env(display), capture_output=True, text=True, timeout=60
        )
    assert result.returncode == 0 and result.stdout.strip().endswith("x11"), result.stderr
