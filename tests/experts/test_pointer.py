"""The pointer expert (a mouse over the env's frame; PushT's target position), driven by posted mouse
events in a virtual X display (tests/xvfb.py): alone, and as the person of take-over DAgger around a
diffusion learner that executes chunks."""

from __future__ import annotations

import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from xvfb import xvfb  # noqa: F401 (the fixture)

import cli
from imitation.data.mcap.reader import DemoFile
from imitation.envs.make import make_env
from imitation.errors import ImitationError
from imitation.experts.pointer import PointerExpert
from imitation.experts.window import HUD_HEIGHT, ControlStatus

pygame = pytest.importorskip("pygame")
on_xvfb = pytest.mark.usefixtures("xvfb")
PUSHT = "gym_pusht/PushT-v0"


def mouse(kind: int, x: int, y: int) -> None:
    event = {"pos": (x, y)} if kind == pygame.MOUSEMOTION else {"pos": (x, y), "button": 1}
    pygame.event.post(pygame.event.Event(kind, **event))


@on_xvfb
def test_the_pointer_over_the_frame_is_the_target_and_a_held_button_takes_over() -> None:
    env = make_env(PUSHT, render_mode="rgb_array")
    observation, _ = env.reset(seed=0)
    expert = PointerExpert(env, fps=1000)
    try:
        np.testing.assert_array_equal(expert(observation), [256, 256])  # the centre until the pointer moves
        width, height = expert._frame.get_width(), expert._frame.get_height()
        mouse(pygame.MOUSEMOTION, width // 2, HUD_HEIGHT + height // 4)
        action = expert(observation)
        assert action.dtype == np.float32 and not expert.engaged
        np.testing.assert_allclose(action, [256, 128], atol=512 / width)
        mouse(pygame.MOUSEBUTTONDOWN, width, HUD_HEIGHT + height)  # the frame's far corner: the bounds' high ends
        np.testing.assert_allclose(expert(observation), [512, 512])
        assert expert.engaged
        mouse(pygame.MOUSEMOTION, -40, 0)  # off the frame, over the strip: clipped to the frame's edge
        np.testing.assert_allclose(expert(observation), [0, 0])
        mouse(pygame.MOUSEBUTTONUP, 0, 0)
        expert(observation)
        assert not expert.engaged
    finally:
        expert.close()


@on_xvfb
def test_actions_that_are_no_point_are_refused() -> None:
    with pytest.raises(ImitationError, match=r"^--expert pointer needs actions that are a point \(a Box of 2 numbers\); Pendulum-v1 has \(1,\)$"):
        PointerExpert(gym.make("Pendulum-v1", render_mode="rgb_array"))


TAKEOVER = range(10, 20)  # the steps the person holds the button, pointing at (128, 384)


@on_xvfb
def test_takeover_dagger_around_a_diffusion_learner_records_the_pointed_targets(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    original = PointerExpert.show_status

    def show_status(self: PointerExpert, status: ControlStatus) -> None:
        if self._frame is not None:
            x, y = self._frame.get_width() // 4, HUD_HEIGHT + 3 * self._frame.get_height() // 4
            if status.step == TAKEOVER.start:
                mouse(pygame.MOUSEBUTTONDOWN, x, y)
            elif status.step == TAKEOVER.stop:
                mouse(pygame.MOUSEBUTTONUP, x, y)
        original(self, status)

    monkeypatch.setattr(PointerExpert, "show_status", show_status)
    out = tmp_path / "takeover"
    argv = ["train", "dagger", "--env", PUSHT, "--expert", "pointer", "--mode", "takeover", "--policy", "diffusion", "--chunk", "4",
            "--hidden", "16", "--rounds", "1", "--episodes-per-round", "1", "--epochs", "1", "--speed", "4", "--quiet", "--out", str(out)]
    assert cli.main(argv) == 0
    (episode,) = DemoFile(out / "rounds" / "round-01.mcap").read_episodes()
    interventions = episode.interventions
    assert np.flatnonzero(interventions.human).tolist() == list(TAKEOVER)
    np.testing.assert_allclose(interventions.executed_actions[TAKEOVER.start : TAKEOVER.stop], [[128, 384]] * len(TAKEOVER), atol=2)
    assert json.loads((out / "config.json").read_text())["policy"]["kind"] == "diffusion"
