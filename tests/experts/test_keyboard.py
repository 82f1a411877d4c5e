"""The keyboard expert, driven headless: SDL's dummy video driver and posted key events."""

from __future__ import annotations

import os

import gymnasium as gym
import pytest
from support import run_cli
from test_cli import assert_one_line_error

from imitation.errors import ImitationError
from imitation.experts.keyboard import KeyboardExpert, key_bindings

os.environ["SDL_VIDEODRIVER"] = "dummy"
pygame = pytest.importorskip("pygame")


def press(key: int, down: bool = True) -> None:
    pygame.event.post(pygame.event.Event(pygame.KEYDOWN if down else pygame.KEYUP, key=key))


def test_held_keys_choose_actions_and_no_key_is_noop() -> None:
    env = gym.make("CartPole-v1", render_mode="rgb_array")
    observation, _ = env.reset(seed=0)
    expert = KeyboardExpert(env, fps=1000)
    try:
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
        assert pygame.display.get_surface().get_size() == env.render().shape[1::-1]
    finally:
        expert.close()


def test_escape_stops_like_ctrl_c() -> None:
    env = gym.make("MountainCar-v0", render_mode="rgb_array")
    observation, _ = env.reset(seed=0)
    expert = KeyboardExpert(env, fps=1000)
    try:
        assert expert(observation) == 1  # MountainCar's no-op
        press(pygame.K_ESCAPE)
        with pytest.raises(KeyboardInterrupt):
            expert(observation)
    finally:
        expert.close()


def test_bindings_for_unknown_discrete_envs_use_digits() -> None:
    gym.register("TestThreeActions-v0", entry_point="gymnasium.envs.classic_control.cartpole:CartPoleEnv")
    env = gym.make("TestThreeActions-v0")
    env.action_space = gym.spaces.Discrete(3)
    assert key_bindings(env) == ({"0": 0, "1": 1, "2": 2}, 0)


def test_continuous_envs_are_refused(tmp_path) -> None:
    with pytest.raises(ImitationError, match="needs a discrete action space; Pendulum-v1 has Box actions"):
        key_bindings(gym.make("Pendulum-v1"))
    result = run_cli("record", "--env", "Pendulum-v1", "--expert", "keyboard", "--out", str(tmp_path / "x.mcap"), env={**os.environ, "SDL_VIDEODRIVER": "dummy"})
    assert_one_line_error(result, "discrete action space")
    assert list(tmp_path.iterdir()) == []


def test_a_keyboard_episode_is_recorded(tmp_path) -> None:
    from imitation.data.mcap.reader import DemoFile
    from imitation.data.mcap.writer import DemoWriter
    from imitation.data.recorder import RecordEpisodes, run_episodes

    env = gym.make("CartPole-v1", render_mode="rgb_array")
    expert = KeyboardExpert(env, fps=1000)
    press(pygame.K_RIGHT)  # held for the whole episode: the pole falls within a few dozen steps
    try:
        with DemoWriter(tmp_path / "human.mcap", env_id="CartPole-v1", observation_space=env.observation_space, action_space=env.action_space) as writer:
            run_episodes(RecordEpisodes(env, writer), expert, episodes=1, seed=0, progress=False)
    finally:
        expert.close()
    episode = DemoFile(tmp_path / "human.mcap")[0]
    assert episode.terminated and len(episode) < 100 and set(episode.actions.tolist()) == {1}
