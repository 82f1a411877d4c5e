"""npz rollouts → demos: stable-baselines' GAIL experts (../shared/testdata/experts) and
HumanCompatibleAI/imitation's flat format, whose pickled `infos` must never be unpickled."""

from __future__ import annotations

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
