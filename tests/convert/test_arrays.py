"""Bare (episodes, steps, columns) arrays → demos through a layout file (issue 17): MountainCar-v0
play shipped as one padded array, as human demo sets are, whose converted returns must be the
env's own."""

from __future__ import annotations

import re
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import yaml
from support import run_cli_many
from test_cli import last_json

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


# Demos that ran past the goal (issue 51, item 4): a published set of 20 human MountainCar demos
# is an array of (position, velocity, action) rows, 130 per episode, the recorder stepping on after
# the car reached the flag. Read as it is, every demo takes 129 steps (return −129), and a policy
# that stops at the flag is scored above the demos. `ends: terminal_state` ends each where
# --env's own termination rule first holds on the recorded states.
PAST_GOAL_ROWS = 130
PAST_GOAL_LAYOUT = {"columns": ["position", "velocity", "action"], "observation": ["position", "velocity"], "action": ["action"],
                    "discrete_action": True, "rows": "state", "reward": -1}


class PastGoal:
    """One demo recorded as that set was: a row (position, velocity, action) per step for a fixed
    number of rows, the env stepped on (its unwrapped self, past any end) after it terminated.
    `ended`: the steps until the env first said terminated, or None."""

    def __init__(self, env_id: str, seed: int, noise: float) -> None:
        env = gym.make(env_id)
        rng = np.random.default_rng(seed)
        observation, _ = env.reset(seed=seed)
        self.rows, self.ended = [], None
        for t in range(PAST_GOAL_ROWS):
            action = 2 if observation[1] >= 0 else 0
            if rng.random() < noise:
                action = int(rng.integers(3))
            self.rows.append([*observation.tolist(), action])
            observation, _, terminated, _, _ = env.unwrapped.step(action)
            if terminated and self.ended is None:
                self.ended = t + 1
        self.rows = np.array(self.rows)


def past_goal_set(env_id: str = "MountainCar-v0") -> list[PastGoal]:
    """19 pushers that reach the flag in 114-124 steps, and a clumsy one that never does."""
    demos = [PastGoal(env_id, seed, 0.0) for seed in range(19)] + [PastGoal(env_id, 19, 0.9)]
    return demos


def test_demos_that_ran_past_the_goal_end_where_the_env_terminates(tmp_path: Path) -> None:
    demos = past_goal_set()
    ended = [d.ended for d in demos]
    assert all(e is not None and e < PAST_GOAL_ROWS - 1 for e in ended[:19]) and ended[19] is None, ended
    path = tmp_path / "human.npy"
    np.save(path, np.stack([d.rows for d in demos]))
    as_recorded, layout = tmp_path / "as-recorded.yaml", tmp_path / "layout.yaml"
    as_recorded.write_text(yaml.safe_dump(PAST_GOAL_LAYOUT))
    layout.write_text(yaml.safe_dump({**PAST_GOAL_LAYOUT, "ends": "terminal_state"}))
    before, after, info = run_cli_many([
        ["convert", path, "--layout", as_recorded, "--env", "MountainCar-v0", "--out", tmp_path / "before.mcap", "--quiet"],
        ["convert", path, "--layout", layout, "--env", "MountainCar-v0", "--out", tmp_path / "after.mcap", "--quiet", "--json"],
        ["info", tmp_path / "after.mcap"],
    ])
    assert before.returncode == 0, before.stderr
    read_as_recorded = DemoFile(tmp_path / "before.mcap").read_episodes()
    assert {len(e) for e in read_as_recorded} == {PAST_GOAL_ROWS - 1} and {e.episode_return for e in read_as_recorded} == {-129.0}
    result = last_json(after)
    kept = [e if e is not None else PAST_GOAL_ROWS - 1 for e in ended]
    episodes = DemoFile(tmp_path / "after.mcap").read_episodes()
    assert [len(e) for e in episodes] == kept
    assert [e.episode_return for e in episodes] == [-float(n) for n in kept]  # the env's return, −1 a step until the flag
    assert [(e.terminated, e.truncated) for e in episodes] == [(True, False)] * 19 + [(False, True)]
    assert [e.metadata["steps_cut"] for e in episodes] == [PAST_GOAL_ROWS - 1 - n for n in kept]
    for episode, demo, n in zip(episodes, demos, kept):
        np.testing.assert_array_equal(episode.observations, demo.rows[: n + 1, :2].astype(np.float32))
        assert episode.actions.tolist() == demo.rows[:n, 2].astype(int).tolist()
    cut = sum(PAST_GOAL_ROWS - 1 - n for n in kept)
    assert result["end_flags"] == {"decided": "terminal_state", "env_id": "MountainCar-v0", "steps_cut": cut, "terminated": 19,
                                   "truncated": 1}
    assert result["transitions"] == sum(kept)
    assert (f"19 of 20 episodes reach a terminal state of MountainCar-v0; the {cut} steps recorded after it were cut "
            "(episode metadata steps_cut), and the 1 that never reach one are truncated") in after.stderr
    assert info.returncode == 0, info.stderr
    assert (f"end flags:     each episode ends where MountainCar-v0's termination rule first holds on its recorded states "
            f"(19 terminated there, {cut} steps recorded after it cut; 1 truncated, never reaching one)") in info.stdout


gym.register("MountainCarFastAtTheFlag-v0", entry_point="gymnasium.envs.classic_control.mountain_car:MountainCarEnv",
             kwargs={"goal_velocity": 0.05}, max_episode_steps=200)


def test_the_rule_is_the_envs_own_and_next_state_rows_in_an_npz(tmp_path: Path) -> None:
    """The same dynamics with a stricter goal (MountainCarEnv's goal_velocity, registered here):
    the demos are cut where that env says, not where MountainCar-v0 would; and rows that hold
    (s_{t+1}, a_t), as recorders that append after env.step write them, in an npz member."""
    demos = past_goal_set("MountainCarFastAtTheFlag-v0")
    ended = [d.ended for d in demos]
    plain = [d.ended for d in past_goal_set()]
    # Row t holds s_{t+1}: s_0 is stored nowhere, so the demo's transitions are those into s_2 ... s_129.
    reached = [e is not None and 2 <= e <= PAST_GOAL_ROWS - 1 for e in ended]
    assert sum(reached) >= 10 and not all(reached), ended
    assert all(strict > loose for strict, loose, r in zip(ended, plain, reached) if r)  # the stricter goal is reached later
    path, layout = tmp_path / "demos.npz", tmp_path / "layout.yaml"
    next_state = [np.column_stack([d.rows[1:, :2], d.rows[:-1, 2]]) for d in demos]
    np.savez(path, demos=np.stack(next_state), seeds=np.arange(20))
    layout.write_text(yaml.safe_dump({**PAST_GOAL_LAYOUT, "rows": "next_state", "ends": "terminal_state", "array": "demos"}))
    result = convert(path, tmp_path / "d.mcap", layout_path=layout, env_id="MountainCarFastAtTheFlag-v0", progress=False)
    episodes = DemoFile(tmp_path / "d.mcap").read_episodes()
    # The first action has no stored state to be taken in: each demo starts at s_1.
    assert [len(e) for e in episodes] == [e - 1 if r else PAST_GOAL_ROWS - 2 for e, r in zip(ended, reached)]
    assert [e.terminated for e in episodes] == reached and [e.truncated for e in episodes] == [not r for r in reached]
    assert result["end_flags"]["decided"] == "terminal_state" and result["end_flags"]["terminated"] == sum(reached)


gym.register("MountainCarShortLimit-v0", entry_point="gymnasium.envs.classic_control.mountain_car:MountainCarEnv",
             max_episode_steps=116)


def test_demos_longer_than_the_time_limit_are_kept_and_named(tmp_path: Path) -> None:
    """The env's time limit does not cut demos (their recorder had none): those still longer after
    the cut are named in a warning."""
    demos = past_goal_set()
    path, layout = write(tmp_path, np.stack([d.rows for d in demos]), {**PAST_GOAL_LAYOUT, "ends": "terminal_state"})
    result = convert(path, tmp_path / "d.mcap", layout_path=layout, env_id="MountainCarShortLimit-v0", progress=False)
    longer = sum(d.ended is None or d.ended > 116 for d in demos)
    assert 0 < longer < len(demos)
    assert result["warnings"][-1] == (f"array {path}: {longer} episode(s) run longer than MountainCarShortLimit-v0's time "
                                      "limit of 116 steps (the env would have truncated them there)")
    assert result["transitions"] == sum(d.ended or PAST_GOAL_ROWS - 1 for d in demos)


def test_demos_the_env_rule_cannot_be_applied_to_are_refused(tmp_path: Path) -> None:
    demos = past_goal_set()[:3]
    array = np.stack([d.rows for d in demos])
    out = tmp_path / "out"
    out.mkdir()
    layout = {**PAST_GOAL_LAYOUT, "ends": "terminal_state"}
    pendulum = {"observation": [0, 1, 2], "action": [3], "rows": "state", "reward": -1, "ends": "terminal_state"}
    cheetah = {"observation": list(range(17)), "action": list(range(17, 23)), "rows": "state", "reward": -1, "ends": "terminal_state"}
    cases = [
        (array, layout, None, "ends: terminal_state ends each episode where the env's termination rule first holds on its "
                              "recorded states, and no --env was given; give --env ID"),
        (np.zeros((2, 4, 4)), pendulum, "Pendulum-v1", "Pendulum-v1's observation is not its state (its `state` has shape [2], its observation [3])"),
        (np.zeros((2, 4, 23)), cheetah, "HalfCheetah-v5", "HalfCheetah-v5's observation is not its state (it keeps no `state`)"),
        # rows that hold (s_t, a_t) read as (a_t, s_{t+1}): the states do not follow one from another by the env's step
        (array, {**layout, "rows": "next_state"}, "MountainCar-v0", "these are not MountainCar-v0's states"),
    ]
    for k, (data, case_layout, env_id, message) in enumerate(cases):
        path, layout_path = write(tmp_path, data, case_layout, f"case{k}.npy")
        with pytest.raises(ImitationError, match=re.escape(message)):
            convert(path, out / "d.mcap", layout_path=layout_path, env_id=env_id, progress=False)
    assert list(out.iterdir()) == []
