"""`imitation train dagger` with a person as the expert, in a real window on a virtual X display
(tests/xvfb.py): key and joystick events go through pygame's own event queue, posted step by
step, and the round files must hold exactly the commands injected.

The events are posted when the DAgger loop shows the window its status before asking the
person for step t (`show_status`, wrapped here to post the events scripted for step t and then
do its work), so the person "acts" on every step deterministically, however fast the machine.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from xvfb import xvfb  # noqa: F401 (the fixture)

import cli
from imitation.data.mcap.reader import DemoFile
from imitation.experts.gamepad import GamepadExpert
from imitation.experts.keyboard import KeyboardExpert
from imitation.experts.window import ControlStatus

pygame = pytest.importorskip("pygame")
on_xvfb = pytest.mark.usefixtures("xvfb")


def inject(monkeypatch: pytest.MonkeyPatch, expert: type, post) -> list[ControlStatus]:
    """Make `expert.show_status` post `post(status)`'s events first; the statuses shown."""
    shown: list[ControlStatus] = []
    original = expert.show_status

    def show_status(self, status: ControlStatus) -> None:
        shown.append(status)
        for event in post(status):
            pygame.event.post(event)
        original(self, status)

    monkeypatch.setattr(expert, "show_status", show_status)
    return shown


def right_held(step: int) -> bool:
    """The keyboard script: RIGHT held for steps 0-2 of every 7, LEFT for the rest."""
    return step % 7 < 3


def key_events(status: ControlStatus) -> list:
    step = status.step
    if step == 0 or right_held(step) != right_held(step - 1):
        pressed, released = (pygame.K_RIGHT, pygame.K_LEFT) if right_held(step) else (pygame.K_LEFT, pygame.K_RIGHT)
        return [pygame.event.Event(pygame.KEYUP, key=released), pygame.event.Event(pygame.KEYDOWN, key=pressed)]
    return []


@on_xvfb
def test_train_dagger_with_the_keyboard_records_the_injected_keys_as_labels(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    out = tmp_path / "keyboard"
    shown = inject(monkeypatch, KeyboardExpert, key_events)
    code = cli.main(["train", "dagger", "--env", "CartPole-v1", "--expert", "keyboard", "--rounds", "2", "--episodes-per-round", "1",
                     "--epochs", "2", "--hidden", "16", "--speed", "4", "--quiet", "--out", str(out)])
    assert code == 0
    assert {status.round for status in shown} == {1, 2}
    for round_index in (1, 2):
        (episode,) = DemoFile(out / "rounds" / f"round-{round_index:02d}.mcap").read_episodes()
        expected = np.array([1 if right_held(t) else 0 for t in range(len(episode))])
        np.testing.assert_array_equal(episode.actions, expected)  # every state labelled with the key held
        assert episode.interventions is not None and episode.timestamps is not None
        if round_index == 1:  # β = 1: the person drove every step
            assert episode.interventions.human.all()
            np.testing.assert_array_equal(episode.interventions.executed_actions, expected)
        # wall-clock timestamps of a window paced at 4 × 50 frames a second
        assert np.median(np.diff(episode.timestamps)) >= 0.5 / 200 * 1e9


def takeover_events(status: ControlStatus) -> list:
    """The person holds RIGHT on steps 2-4 of each episode, and touches nothing otherwise."""
    if status.step == 2:
        return [pygame.event.Event(pygame.KEYDOWN, key=pygame.K_RIGHT)]
    if status.step == 5:
        return [pygame.event.Event(pygame.KEYUP, key=pygame.K_RIGHT)]
    return []


@on_xvfb
def test_takeover_with_the_keyboard_hands_the_controls_over_while_a_key_is_held(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    out = tmp_path / "takeover"
    shown = inject(monkeypatch, KeyboardExpert, takeover_events)
    code = cli.main(["train", "dagger", "--env", "CartPole-v1", "--expert", "keyboard", "--mode", "takeover", "--rounds", "1",
                     "--episodes-per-round", "1", "--epochs", "2", "--hidden", "16", "--speed", "4", "--quiet", "--out", str(out)])
    assert code == 0
    (episode,) = DemoFile(out / "rounds" / "round-01.mcap").read_episodes()
    assert len(episode) > 6, "the untrained learner keeps the pole up for more than 6 steps from this seed"
    interventions = episode.interventions
    assert np.flatnonzero(interventions.human).tolist() == [2, 3, 4]
    assert interventions.handovers() == [(2, True), (5, False)]
    np.testing.assert_array_equal(interventions.executed_actions[2:5], 1)
    np.testing.assert_array_equal(episode.actions, interventions.executed_actions)
    assert [s.human_in_control for s in shown[:7]] == [False, False, False, True, True, True, False]
    assert [s.interventions for s in shown[:4]] == [0, 0, 0, 1]


def axis_value(step: int) -> float:
    """The joystick script: axis 0 swings as sin(t/6), two decimals (beyond the dead zone where |v| > 0.15)."""
    return round(float(np.sin(step / 6)), 2)


def stick_events(status: ControlStatus) -> list:
    return [pygame.event.Event(pygame.JOYAXISMOTION, joy=0, instance_id=0, axis=0, value=axis_value(status.step))]


@on_xvfb
def test_train_dagger_with_a_virtual_joystick_records_the_stick_as_labels(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Pendulum's torque is 2 × the stick's deflection (0 within the dead zone)."""
    out = tmp_path / "gamepad"
    inject(monkeypatch, GamepadExpert, stick_events)
    code = cli.main(["train", "dagger", "--env", "Pendulum-v1", "--expert", "gamepad", "--rounds", "2", "--episodes-per-round", "1",
                     "--epochs", "2", "--hidden", "16", "--speed", "4", "--quiet", "--out", str(out)])
    assert code == 0
    for round_index in (1, 2):
        (episode,) = DemoFile(out / "rounds" / f"round-{round_index:02d}.mcap").read_episodes()
        values = np.array([axis_value(t) for t in range(len(episode))])
        expected = np.where(np.abs(values) > 0.15, 2 * values, 0.0).astype(np.float32).reshape(-1, 1)
        assert len(episode) == 200 and episode.actions.dtype == np.float32
        np.testing.assert_array_equal(episode.actions, expected)
