"""Bare (episodes, steps, columns) arrays → demos through a layout file (issue 17): MountainCar-v0
play shipped as one padded array, as human demo sets are, whose converted returns must be the
env's own."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import yaml

from imitation.data.convert.job import convert
from imitation.data.mcap.reader import DemoFile
from imitation.errors import ImitationError

# Per-episode chance of a random key press: a human who sometimes pushes the wrong way. Some
# episodes reach the flag, the clumsiest run into the 200-step time limit.
NOISES = [0.0, 0.02, 0.04, 0.06, 0.08, 0.1, 0.0, 0.03, 0.05, 0.9]


class Play:
    """One MountainCar-v0 episode as the env saw it."""

    def __init__(self, seed: int, noise: float) -> None:
        env = gym.make("MountainCar-v0")
        rng = np.random.default_rng(seed)
        observation, _ = env.reset(seed=seed)
        self.observations, self.actions, self.rewards = [observation], [], []
        terminated = truncated = False
        while not (terminated or truncated):
            action = 2 if observation[1] > 0 else 0  # push along the velocity: pump energy
            if rng.random() < noise:
                action = int(rng.integers(3))
            observation, reward, terminated, truncated, _ = env.step(action)
            self.observations.append(observation)
            self.actions.append(action)
            self.rewards.append(float(reward))
        self.terminated, self.truncated = terminated, truncated
        self.observations = np.array(self.observations)

    @property
    def steps(self) -> int:
        return len(self.actions)

    @property
    def episode_return(self) -> float:
        return sum(self.rewards)


@pytest.fixture(scope="module")
def plays() -> list[Play]:
    plays = [Play(seed, noise) for seed, noise in enumerate(NOISES)]
    assert {p.terminated for p in plays} == {True, False}  # both kinds of end are in the data
    return plays


def padded(rows: list[np.ndarray], length: int, fill: float = np.nan) -> np.ndarray:
    """Episodes of rows, padded to a common length as such data sets are shipped."""
    array = np.full((len(rows), length, rows[0].shape[1]), fill)
    for k, episode in enumerate(rows):
        array[k, : len(episode)] = episode
    return array


def state_rows(play: Play) -> np.ndarray:
    """Row t = (position_t, velocity_t, action_t); the last row holds the final state, no action."""
    return np.column_stack([play.observations, np.append(np.array(play.actions, float), np.nan)])


def next_state_rows(play: Play) -> np.ndarray:
    """Row t = (position_{t+1}, velocity_{t+1}, action_t): the state each key press led to (as
    recorders that append after `env.step` write it); the starting state is nowhere."""
    return np.column_stack([play.observations[1:], np.array(play.actions, float)])


LAYOUT = {"columns": ["position", "velocity", "action"], "observation": ["position", "velocity"], "action": "action",
          "discrete_action": True, "rows": "state", "final_state": "row", "padding": "nan", "reward": -1}


def write(tmp_path: Path, array: np.ndarray, layout: dict, name: str = "demos.npy") -> tuple[Path, Path]:
    path = tmp_path / name
    np.save(path, array)
    layout_path = tmp_path / f"{name}.layout.yaml"
    layout_path.write_text(yaml.safe_dump(layout))
    return path, layout_path


def test_padded_state_rows_give_the_env_returns_and_ends(tmp_path: Path, plays: list[Play]) -> None:
    longest = max(p.steps for p in plays) + 1
    array = padded([state_rows(p) for p in plays], longest + 7)  # slots longer than any episode
    path, layout = write(tmp_path, array, LAYOUT)
    result = convert(path, tmp_path / "d.mcap", layout_path=layout, env_id="MountainCar-v0", progress=False)
    demo = DemoFile(tmp_path / "d.mcap")
    episodes = demo.read_episodes()
    assert [len(e) for e in episodes] == [p.steps for p in plays]
    assert [e.episode_return for e in episodes] == [p.episode_return for p in plays]  # -1 a step, every step counted
    assert np.mean([e.episode_return for e in episodes]) == np.mean([p.episode_return for p in plays])
    assert [(e.terminated, e.truncated) for e in episodes] == [(p.terminated, p.truncated) for p in plays]
    for episode, play in zip(episodes, plays):
        assert np.array_equal(episode.observations, play.observations)  # the final state included
        assert episode.actions.tolist() == play.actions
    assert demo.action_space == gym.spaces.Discrete(3) and demo.env_id == "MountainCar-v0"
    terminated = sum(p.terminated for p in plays)
    assert demo.end_flags == result["end_flags"] == {"decided": "time_limit", "source_flag": "padding", "env_id": "MountainCar-v0",
                                                     "max_episode_steps": 200, "terminated": terminated, "truncated": len(plays) - terminated}
    assert result["warnings"] == []


def test_reading_the_same_array_naively_gets_the_return_wrong(tmp_path: Path, plays: list[Play]) -> None:
    """The trap the layout avoids: taking every row of a slot as a step (padding none) counts the
    padding and the final state's missing action as steps."""
    array = np.nan_to_num(padded([state_rows(p) for p in plays], 201, fill=0.0), nan=0.0)  # zeros after the end
    path, layout = write(tmp_path, array, {**LAYOUT, "padding": 0})
    right = DemoFile(convert(path, tmp_path / "right.mcap", layout_path=layout, env_id="MountainCar-v0", progress=False)["out"])
    assert [f.episode_return for f in right.episodes] == [p.episode_return for p in plays]
    naive = write(tmp_path, array, {**LAYOUT, "padding": "none", "ends": "truncated"}, "naive.npy")
    wrong = DemoFile(convert(naive[0], tmp_path / "wrong.mcap", layout_path=naive[1], progress=False)["out"])
    assert [f.episode_return for f in wrong.episodes] == [-200.0] * len(plays)


def test_final_state_none_drops_the_last_step_and_says_so(tmp_path: Path, plays: list[Play]) -> None:
    rows = [state_rows(p)[:-1] for p in plays]  # no final-state row: every row has an action
    path, layout = write(tmp_path, padded(rows, 200), {**LAYOUT, "final_state": "none"})
    result = convert(path, tmp_path / "d.mcap", layout_path=layout, env_id="MountainCar-v0", progress=False)
    demo = DemoFile(tmp_path / "d.mcap")
    episodes = demo.read_episodes()
    assert [len(e) for e in episodes] == [p.steps - 1 for p in plays]
    assert all(e.truncated and not e.terminated for e in episodes)  # each stops one step before its end
    assert [e.metadata["source_return"] for e in episodes] == [p.episode_return for p in plays]
    assert [e.metadata["source_end"] for e in episodes] == ["terminated" if p.terminated else "time_limit" for p in plays]
    for episode, play in zip(episodes, plays):
        assert np.array_equal(episode.observations, play.observations[:-1])
    assert demo.end_flags["final_observation"] is False and demo.end_flags["source_terminated"] == sum(p.terminated for p in plays)
    assert any("last action and reward were dropped" in w for w in result["warnings"])


def test_next_state_rows_keep_the_end_and_lose_the_start(tmp_path: Path, plays: list[Play]) -> None:
    path, layout = write(tmp_path, padded([next_state_rows(p) for p in plays], 200), {**LAYOUT, "rows": "next_state", "final_state": None})
    raw = yaml.safe_load(layout.read_text())
    del raw["final_state"]
    layout.write_text(yaml.safe_dump(raw))
    result = convert(path, tmp_path / "d.mcap", layout_path=layout, env_id="MountainCar-v0", progress=False)
    episodes = DemoFile(tmp_path / "d.mcap").read_episodes()
    # s_0 is not stored, so the first key press has no state to be taken in: dropped, and said.
    assert [len(e) for e in episodes] == [p.steps - 1 for p in plays]
    assert [e.episode_return for e in episodes] == [p.episode_return + 1 for p in plays]
    assert [e.metadata["source_return"] for e in episodes] == [p.episode_return for p in plays]
    assert [(e.terminated, e.truncated) for e in episodes] == [(p.terminated, p.truncated) for p in plays]  # the end is exact
    for episode, play in zip(episodes, plays):
        assert np.array_equal(episode.observations, play.observations[1:]) and episode.actions.tolist() == play.actions[1:]
    assert any("first action and reward were dropped" in w for w in result["warnings"])


def test_repeat_padding_an_npz_member_and_a_reward_column(tmp_path: Path, plays: list[Play]) -> None:
    rows = [np.column_stack([state_rows(p), np.append(p.rewards, 0.0)]) for p in plays]
    array = np.stack([np.concatenate([r, np.repeat(r[-1:], 205 - len(r), axis=0)]) for r in rows])  # the last row again
    path = tmp_path / "demos.npz"
    np.savez(path, demos=array, seeds=np.arange(len(plays)))
    layout = tmp_path / "layout.yaml"
    layout.write_text(yaml.safe_dump({**LAYOUT, "columns": ["position", "velocity", "action", "reward"], "padding": "repeat",
                                      "reward": {"column": "reward"}, "array": "demos"}))
    result = convert(path, tmp_path / "d.mcap", layout_path=layout, env_id="MountainCar-v0", progress=False)
    assert result["from"] == "array"
    demo = DemoFile(tmp_path / "d.mcap")
    assert [f.episode_return for f in demo.episodes] == [p.episode_return for p in plays]
    assert [(f.terminated, f.truncated) for f in demo.episodes] == [(p.terminated, p.truncated) for p in plays]


def test_ends_stated_by_the_layout_without_env(tmp_path: Path, plays: list[Play]) -> None:
    path, layout = write(tmp_path, padded([state_rows(p) for p in plays], 201), {**LAYOUT, "ends": "terminated"})
    convert(path, tmp_path / "d.mcap", layout_path=layout, progress=False)
    demo = DemoFile(tmp_path / "d.mcap")
    assert demo.env_id == "" and demo.action_space == gym.spaces.Discrete(3)
    assert all(f.terminated for f in demo.episodes)
    assert demo.end_flags == {"decided": "layout", "layout_ends": "terminated", "terminated": len(plays), "truncated": 0}


def test_bad_arrays_and_layouts_are_refused_and_write_nothing(tmp_path: Path, plays: list[Play]) -> None:
    array = padded([state_rows(p) for p in plays], 201)
    hole = array.copy()
    hole[2, 150:160] = np.nan  # an episode whose padding stops, then data again
    hole[2, 160:, :] = 1.0
    out = tmp_path / "out"
    out.mkdir()
    cases = [
        (array, LAYOUT, None, "ends: time_limit decides each episode's end from the env's time limit, and no --env was given"),
        (hole, LAYOUT, "MountainCar-v0", "episode 2: row 160 holds data after padding starts at row 150"),
        (array, {**LAYOUT, "observation": ["position", "speed"]}, "MountainCar-v0", "observation: no column 'speed'"),
        (array, {**LAYOUT, "rows": "after"}, "MountainCar-v0", "rows must be state or next_state, got after"),
        (array, {**LAYOUT, "stride": 2}, "MountainCar-v0", "unknown key 'stride'"),
        (array[0], LAYOUT, "MountainCar-v0", "expected numbers of shape (episodes, steps, columns), got float64 of shape [201, 3]"),
    ]
    for k, (data, layout, env_id, message) in enumerate(cases):
        path, layout_path = write(tmp_path, data, layout, f"case{k}.npy")
        with pytest.raises(ImitationError, match=message.replace("(", r"\(").replace(")", r"\)").replace("[", r"\[")):
            convert(path, out / "d.mcap", layout_path=layout_path, env_id=env_id, progress=False)
    assert list(out.iterdir()) == []
