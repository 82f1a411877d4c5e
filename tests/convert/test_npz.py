"""npz rollouts → demos: stable-baselines' GAIL experts (../shared/testdata/experts) and
HumanCompatibleAI/imitation's flat format, whose pickled `infos` must never be unpickled."""

from __future__ import annotations

import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

from imitation.data.convert.job import convert
from imitation.data.convert.npz import npz_to_episodes
from imitation.data.mcap.reader import DemoFile
from imitation.errors import ImitationError

UNPICKLED: list[str] = []


def _record_unpickling() -> dict:
    UNPICKLED.append("infos")
    return {}


class Tripwire:
    """Pickles as a call to `_record_unpickling`: loading it would leave a trace."""

    def __reduce__(self):
        return (_record_unpickling, ())


def test_stable_baselines_cartpole_expert(testdata: Path, tmp_path: Path) -> None:
    path = testdata / "experts" / "expert_cartpole.npz"
    raw = np.load(path, allow_pickle=False)
    starts = np.flatnonzero(raw["episode_starts"])
    lengths = np.diff(np.append(starts, len(raw["obs"])))
    converted = npz_to_episodes(path)
    assert len(converted.episodes) == 100 == len(raw["episode_returns"])
    assert converted.action_space == gym.spaces.Discrete(2) and converted.observation_space.shape == (4,)
    # All L observations of an episode are kept; its last action (no following observation) is not.
    assert [len(e) for e in converted.episodes] == (lengths - 1).tolist()
    second = converted.episodes[1]
    assert np.array_equal(second.observations, raw["obs"][starts[1] : starts[2]])
    assert np.array_equal(second.actions, raw["actions"][starts[1] : starts[2] - 1, 0])
    assert second.metadata["source_return"] == raw["episode_returns"][1]
    result = convert(path, tmp_path / "cartpole.mcap", env_id="CartPole-v1", progress=False)
    demo = DemoFile(tmp_path / "cartpole.mcap")
    assert result["transitions"] == demo.num_transitions == int(lengths.sum()) - 100
    assert demo.env_id == "CartPole-v1" and demo.dt == pytest.approx(0.02)  # the env's step, the file has none
    assert demo.observation_space == gym.make("CartPole-v1").observation_space


def test_pendulum_expert_has_continuous_actions(testdata: Path) -> None:
    converted = npz_to_episodes(testdata / "experts" / "expert_pendulum.npz")
    assert isinstance(converted.action_space, gym.spaces.Box) and converted.action_space.shape == (1,)
    assert len(converted.episodes) == 100 and all(len(e) == 199 for e in converted.episodes)


def test_imitation_flat_format_without_unpickling_infos(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    lengths = [3, 5, 2]
    obs = rng.normal(size=(sum(lengths) + len(lengths), 4)).astype(np.float32)
    acts = rng.integers(0, 3, size=sum(lengths))
    rews = rng.normal(size=sum(lengths))
    infos = np.empty(sum(lengths), dtype=object)
    infos[:] = [Tripwire() for _ in range(sum(lengths))]
    path = tmp_path / "rollouts.npz"
    # As imitation's (pre-0.4) `save` wrote it: trajectories one after the other, split points in `indices`.
    np.savez_compressed(path, obs=obs, acts=acts, rews=rews, infos=infos, terminal=np.array([True, False, True]),
                        indices=np.cumsum(lengths[:-1]))
    converted = npz_to_episodes(path)
    assert UNPICKLED == []
    assert [len(e) for e in converted.episodes] == lengths
    assert [e.terminated for e in converted.episodes] == [True, False, True] and converted.episodes[1].truncated
    assert np.array_equal(converted.episodes[1].observations, obs[4:10])  # 3 + 1 rows of the first, then 5 + 1
    assert np.array_equal(converted.episodes[2].actions, acts[8:10]) and np.array_equal(converted.episodes[2].rewards, rews[8:10])
    assert converted.action_space == gym.spaces.Discrete(int(acts.max()) + 1)
    with pytest.raises(ValueError):  # the object array is really there, and really needs pickle
        np.load(path, allow_pickle=False)["infos"]


def test_bad_npz_files(tmp_path: Path) -> None:
    np.savez(tmp_path / "other.npz", x=np.zeros(3))
    with pytest.raises(ImitationError, match="unknown npz layout"):
        npz_to_episodes(tmp_path / "other.npz")
    (tmp_path / "junk.npz").write_bytes(b"PK not a zip")
    with pytest.raises(ImitationError, match="not a readable npz"):
        npz_to_episodes(tmp_path / "junk.npz")
    np.savez(tmp_path / "short.npz", obs=np.zeros((5, 2)), acts=np.zeros(2), indices=np.array([1]), terminal=np.array([True, True]))
    with pytest.raises(ImitationError, match="inconsistent trajectories"):
        npz_to_episodes(tmp_path / "short.npz")
    np.savez(tmp_path / "order.npz", obs=np.zeros((4, 2)), acts=np.zeros(2), indices=np.array([3]), terminal=np.array([True, True]))
    with pytest.raises(ImitationError, match="increasing split points"):
        npz_to_episodes(tmp_path / "order.npz")


# ------------------------------------------------------------------------------------------------
# End flags: which episodes ended at the time limit and which in a terminal state (issue 17)

IMITATION_FIXTURES = Path(__file__).resolve().parent.parent / "fixtures" / "imitation"


def _source_lengths(path: Path) -> np.ndarray:
    raw = np.load(path, allow_pickle=False)
    starts = np.flatnonzero(raw["episode_starts"])
    return np.diff(np.append(starts, len(raw["obs"])))


@pytest.mark.parametrize("name, env_id, limit", [("expert_cartpole", "CartPole-v1", 500), ("expert_pendulum", "Pendulum-v1", 200)])
def test_stable_baselines_ends_are_decided_from_the_time_limit(testdata: Path, tmp_path: Path, name: str, env_id: str, limit: int) -> None:
    path = testdata / "experts" / f"{name}.npz"
    lengths = _source_lengths(path)  # rows = env steps of each source episode
    result = convert(path, tmp_path / "d.mcap", env_id=env_id, progress=False)
    demo = DemoFile(tmp_path / "d.mcap")
    # The format keeps no final observation: every demo stops one step before its episode ended,
    # so none may claim its final observation is terminal.
    assert [(f.terminated, f.truncated) for f in demo.episodes] == [(False, True)] * len(lengths)
    expected = ["time_limit" if n == limit else "terminated" for n in lengths]
    assert [f.metadata["source_end"] for f in demo.episodes] == expected
    flags = {"decided": "time_limit", "source_flag": "episode_starts", "final_observation": False, "env_id": env_id,
             "max_episode_steps": limit, "source_terminated": expected.count("terminated"),
             "source_time_limit": expected.count("time_limit"), "terminated": 0, "truncated": len(lengths)}
    assert demo.end_flags == result["end_flags"] == flags
    assert (flags["source_terminated"], flags["source_time_limit"]) == {"CartPole-v1": (1, 99), "Pendulum-v1": (0, 100)}[env_id]


def test_stable_baselines_without_env_says_it_does_not_know(testdata: Path, tmp_path: Path) -> None:
    result = convert(testdata / "experts" / "expert_cartpole.npz", tmp_path / "d.mcap", progress=False)
    demo = DemoFile(tmp_path / "d.mcap")
    assert all(f.truncated and not f.terminated and "source_end" not in f.metadata for f in demo.episodes)
    assert demo.end_flags == {"decided": "unknown", "source_flag": "episode_starts", "final_observation": False, "terminated": 0, "truncated": 100}
    assert any("does not say whether its episodes ended in a terminal state or at a time limit" in w for w in result["warnings"])


def _fixture(name: str) -> tuple[Path, dict]:
    return IMITATION_FIXTURES / f"{name}.npz", json.loads((IMITATION_FIXTURES / f"{name}.json").read_text())


def test_imitation_npz_written_by_imitation_keeps_its_terminal_flags_without_env(tmp_path: Path) -> None:
    path, facts = _fixture("cartpole")
    with pytest.raises(ValueError):  # imitation's own infos: a pickled object array, never loaded
        np.load(path, allow_pickle=False)["infos"]
    result = convert(path, tmp_path / "d.mcap", progress=False)
    demo = DemoFile(tmp_path / "d.mcap")
    # imitation wrote terminal=True at every end, the five 500-step time limits included: kept, and said so.
    assert facts["terminal"] == [True] * 10 and [len(e) for e in demo] == facts["lengths"]
    assert all(f.terminated and not f.truncated for f in demo.episodes)
    assert demo.end_flags == {"decided": "source", "source_flag": "terminal", "terminated": 10, "truncated": 0}
    warning = next(w for w in result["warnings"] if "cannot tell a time limit from a termination" in w)
    assert "10 episode(s) marked terminated may have ended at a time limit" in warning and "--env" in warning


@pytest.mark.parametrize("name, limit", [("cartpole", 500), ("pendulum", 200)])
def test_imitation_npz_ends_are_decided_from_the_env_time_limit(tmp_path: Path, name: str, limit: int) -> None:
    path, facts = _fixture(name)
    result = convert(path, tmp_path / "d.mcap", env_id=facts["env_id"], progress=False)
    demo = DemoFile(tmp_path / "d.mcap")
    ends = [(f.terminated, f.truncated) for f in demo.episodes]
    assert ends == [(n < limit, n == limit) for n in facts["lengths"]]
    terminated = sum(n < limit for n in facts["lengths"])
    assert (terminated, len(ends) - terminated) == {"cartpole": (5, 5), "pendulum": (0, 3)}[name]
    assert demo.end_flags == result["end_flags"] == {"decided": "time_limit", "source_flag": "terminal", "env_id": facts["env_id"],
                                                     "max_episode_steps": limit, "terminated": terminated, "truncated": len(ends) - terminated}
    assert not any("cannot tell" in w for w in result["warnings"])


def test_record_and_a_converted_imitation_npz_agree(tmp_path: Path) -> None:
    """Replaying each trajectory of imitation's file through record's own machinery (the env's
    reset seed, then its actions) gives the same observations and the same end flags."""
    from imitation.data.mcap.writer import DemoWriter
    from imitation.data.recorder import RecordEpisodes, run_episodes

    path, facts = _fixture("cartpole")
    convert(path, tmp_path / "converted.mcap", env_id="CartPole-v1", progress=False)
    converted = DemoFile(tmp_path / "converted.mcap").read_episodes()
    assert facts["reset_seeds"] == list(range(len(converted)))
    actions = iter(int(a) for episode in converted for a in episode.actions)
    env = gym.make("CartPole-v1")
    with DemoWriter(tmp_path / "recorded.mcap", env_id="CartPole-v1", observation_space=env.observation_space,
                    action_space=env.action_space, end_flags={"decided": "env"}) as writer:
        run_episodes(RecordEpisodes(env, writer), lambda observation: next(actions), episodes=len(converted), seed=0, progress=False)
    recorded = DemoFile(tmp_path / "recorded.mcap").read_episodes()
    assert next(actions, None) is None
    for k, (mine, theirs) in enumerate(zip(recorded, converted)):
        assert np.array_equal(mine.observations, theirs.observations), k
        assert (mine.terminated, mine.truncated) == (theirs.terminated, theirs.truncated), k
    assert sum(e.terminated for e in recorded) == 5 and sum(e.truncated for e in recorded) == 5


def test_an_episode_longer_than_the_time_limit_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "long.npz"
    np.savez(path, obs=np.zeros((504, 4), np.float32), acts=np.zeros(502, np.int64), indices=np.array([1]),
             terminal=np.array([True, True]), rews=np.ones(502))
    with pytest.raises(ImitationError, match=r"episode 1 took 501 steps, more than CartPole-v1's time limit of 500"):
        convert(path, tmp_path / "d.mcap", env_id="CartPole-v1", progress=False)
    assert list(tmp_path.iterdir()) == [path]
