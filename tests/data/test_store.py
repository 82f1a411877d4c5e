"""The MCAP demo store: lossless round trips, lazy and random access, multi-file datasets."""

from __future__ import annotations

import dataclasses
import json

import gymnasium as gym
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from helpers import assert_episodes_equal, random_episode
from test_spaces import all_spaces

from imitation.data.dataset import DemoDataset
from imitation.data.mcap.reader import DemoFile
from imitation.data.mcap.writer import DemoWriter, write_episodes
from imitation.data.types import Episode
from imitation.errors import DemoFileError, ImitationError

BOX4 = gym.spaces.Box(-np.inf, np.inf, (4,), np.float32)
DISCRETE2 = gym.spaces.Discrete(2)


def write(path, episodes, observation_space=BOX4, action_space=DISCRETE2, **options):
    # random_episode's rows are random bytes: NaN and inf included, stored bit for bit.
    options.setdefault("finite_only", False)
    return write_episodes(path, episodes, env_id="Test-v0", observation_space=observation_space, action_space=action_space, **options)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(observation_space=all_spaces, action_space=all_spaces, lengths=st.lists(st.integers(0, 40), min_size=1, max_size=4), block_steps=st.sampled_from([1, 7, 4096]))
def test_any_spaces_round_trip_losslessly(tmp_path, observation_space, action_space, lengths, block_steps) -> None:
    episodes = [random_episode(observation_space, action_space, steps, seed=i, terminated=i % 2 == 0) for i, steps in enumerate(lengths)]
    path = tmp_path / "any.mcap"
    write(path, episodes, observation_space, action_space, block_steps=block_steps)
    demo = DemoFile(path, verify=True)
    assert demo.damage is None
    assert len(demo) == len(episodes)
    for read, original in zip(demo, episodes, strict=True):
        assert_episodes_equal(read, original)
    k = len(episodes) - 1
    assert_episodes_equal(demo[k], episodes[k])


def test_facts_are_known_without_reading_steps(tmp_path) -> None:
    episodes = [random_episode(BOX4, DISCRETE2, steps, seed=steps, terminated=steps == 3) for steps in (3, 10, 5)]
    write(tmp_path / "f.mcap", episodes)
    demo = DemoFile(tmp_path / "f.mcap")
    assert [f.length for f in demo.episodes] == [3, 10, 5]
    assert [f.terminated for f in demo.episodes] == [True, False, False]
    assert [f.episode_return for f in demo.episodes] == pytest.approx([e.episode_return for e in episodes])
    assert [f.metadata["seed"] for f in demo.episodes] == [3, 10, 5]
    assert demo.num_transitions == 18
    assert demo.env_id == "Test-v0" and demo.observation_space == BOX4 and demo.action_space == DISCRETE2


def test_random_access_reads_only_the_chunks_of_that_episode(tmp_path, monkeypatch) -> None:
    episodes = [random_episode(BOX4, DISCRETE2, 50, seed=i) for i in range(40)]
    # Small chunks: one or two episodes each.
    write(tmp_path / "f.mcap", episodes, chunk_size=2_000)
    demo = DemoFile(tmp_path / "f.mcap")
    assert len(demo._index.chunks) >= 20
    decompressed: list[int] = []
    import imitation.data.mcap.records as records

    original = records.decode_chunk

    def counting(record, *args):
        decompressed.append(len(record))
        return original(record, *args)

    monkeypatch.setattr(records, "decode_chunk", counting)
    for k in (37, 0, 21, -1):
        decompressed.clear()
        assert_episodes_equal(demo[k], episodes[k])
        assert len(decompressed) <= 2
    with pytest.raises(IndexError):
        demo[40]


def test_flushed_episodes_are_readable_from_the_partial_file_while_the_writer_is_still_open(tmp_path) -> None:
    """What a `kill -9` would leave: every episode `write` returned for is in `<path>.partial`."""
    episodes = [random_episode(BOX4, DISCRETE2, 20, seed=i) for i in range(7)]
    writer = DemoWriter(tmp_path / "f.mcap", env_id="Test-v0", observation_space=BOX4, action_space=DISCRETE2, flush_episodes=True, finite_only=False)
    try:
        for count, episode in enumerate(episodes, start=1):
            writer.write(episode)
            salvaged = DemoFile(writer.partial_path, salvage=True)
            assert len(salvaged) == count
            assert_episodes_equal(salvaged[count - 1], episode)
    finally:
        writer.close()


def test_iteration_is_lazy(tmp_path, monkeypatch) -> None:
    import imitation.data.mcap.records as records

    write(tmp_path / "f.mcap", [random_episode(BOX4, DISCRETE2, 20, seed=i) for i in range(40)], durable=True)
    demo = DemoFile(tmp_path / "f.mcap")
    assert len(demo._index.chunks) == 40  # durable: one chunk per episode
    read: list[int] = []
    original = records._read_chunk

    def counting(fd, chunk, buffers):
        read.append(chunk.offset)
        return original(fd, chunk, buffers)

    monkeypatch.setattr(records, "_read_chunk", counting)
    iterator = iter(demo)
    assert len(next(iterator)) == 20
    assert len(read) < 10, "only a small window of chunks is read ahead of the first episode"
    assert sum(1 for _ in iterator) == 39


def test_dict_observations_get_one_channel_per_key(tmp_path) -> None:
    space = gym.spaces.Dict({"pos": gym.spaces.Box(-1, 1, (2,), np.float64), "grid": gym.spaces.Dict({"cell": gym.spaces.Discrete(9)})})
    episode = random_episode(space, DISCRETE2, 6, seed=0)
    write(tmp_path / "d.mcap", [episode], observation_space=space)
    demo = DemoFile(tmp_path / "d.mcap")
    assert "/observation/pos" in demo.channels and "/observation/grid/cell" in demo.channels
    assert_episodes_equal(demo[0], episode)


def test_timestamps_and_infos_round_trip(tmp_path) -> None:
    base = random_episode(BOX4, DISCRETE2, 4, seed=0)
    stamps = np.array([5, 7, 20, 21, 40], dtype=np.int64) * 1_000_000
    infos = [{"x": i, "arr": np.arange(2) + i} for i in range(4)]
    episode = Episode(observations=base.observations, actions=base.actions, rewards=base.rewards, truncated=True, timestamps=stamps, infos=infos)
    # The second episode's clock restarts at 0: the writer shifts it after the first.
    second = Episode(observations=base.observations, actions=base.actions, rewards=base.rewards, truncated=True, timestamps=stamps - stamps[0])
    write(tmp_path / "t.mcap", [episode, second])
    demo = DemoFile(tmp_path / "t.mcap")
    first_read, second_read = demo[0], demo[1]
    np.testing.assert_array_equal(first_read.timestamps, stamps)
    assert first_read.infos == [{"x": i, "arr": [i, i + 1]} for i in range(4)]
    assert second_read.infos is None
    # The recording's own clock comes back exactly; the file's log times were shifted.
    np.testing.assert_array_equal(second_read.timestamps, stamps - stamps[0])
    assert demo.episodes[1].time_shift_ns > 0
    assert demo.episodes[1].t_start_ns > demo.episodes[0].t_end_ns


def test_negative_timestamps_round_trip(tmp_path) -> None:
    base = random_episode(BOX4, DISCRETE2, 2, seed=0)
    stamps = np.array([-30, -20, -10], dtype=np.int64)
    episode = Episode(observations=base.observations, actions=base.actions, rewards=base.rewards, truncated=True, timestamps=stamps)
    write(tmp_path / "n.mcap", [episode])
    np.testing.assert_array_equal(DemoFile(tmp_path / "n.mcap")[0].timestamps, stamps)


def test_infos_and_metadata_are_strict_json(tmp_path) -> None:
    base = random_episode(BOX4, DISCRETE2, 2, seed=0)
    infos = [{"x": float("nan"), "y": np.float32(1.5)}, {"z": (1, 2), "w": object}]
    episode = Episode(observations=base.observations, actions=base.actions, rewards=base.rewards, truncated=True, infos=infos, metadata={"gain": np.float64(np.inf)})
    write(tmp_path / "j.mcap", [episode], metadata={"note": np.int64(3)})
    demo = DemoFile(tmp_path / "j.mcap")
    read = demo[0]
    assert read.infos == [{"x": "nan", "y": 1.5}, {"z": [1, 2], "w": repr(object)}]
    assert read.metadata == {"gain": "inf"} and demo.user_metadata == {"note": 3}


def test_bad_writer_arguments_leave_no_file(tmp_path) -> None:
    bad_space = gym.spaces.Dict({"a/b": DISCRETE2})
    with pytest.raises(ImitationError):
        DemoWriter(tmp_path / "x.mcap", finite_only=False, env_id="T", observation_space=bad_space, action_space=DISCRETE2)
    with pytest.raises(ImitationError, match="dt must be a positive"):
        DemoWriter(tmp_path / "x.mcap", finite_only=False, env_id="T", observation_space=BOX4, action_space=DISCRETE2, dt=0.0)
    assert list(tmp_path.iterdir()) == []


def test_lz4_chunks_from_other_writers_are_read(tmp_path) -> None:
    from mcap.writer import CompressionType

    episodes = [random_episode(BOX4, DISCRETE2, 9, seed=i) for i in range(2)]
    writer = DemoWriter(tmp_path / "l.mcap", finite_only=False, env_id="T", observation_space=BOX4, action_space=DISCRETE2)
    # Another MCAP writer could choose lz4; swap the compression on our writer to make such a file.
    writer._writer._Writer__compression = CompressionType.LZ4
    with writer:
        for episode in episodes:
            writer.write(episode)
    demo = DemoFile(tmp_path / "l.mcap", verify=True)
    for read, original in zip(demo, episodes, strict=True):
        assert_episodes_equal(read, original)


def test_simulator_time_is_step_times_dt(tmp_path) -> None:
    write(tmp_path / "s.mcap", [random_episode(BOX4, DISCRETE2, 10, seed=i) for i in range(2)], dt=0.02)
    demo = DemoFile(tmp_path / "s.mcap")
    assert demo.dt == pytest.approx(0.02)
    assert (demo.episodes[0].t_start_ns, demo.episodes[0].t_end_ns) == (0, 10 * 20_000_000)
    assert demo.episodes[1].t_start_ns == 11 * 20_000_000


def test_several_files_form_one_dataset(tmp_path) -> None:
    first = [random_episode(BOX4, DISCRETE2, 5, seed=i) for i in range(3)]
    second = [random_episode(BOX4, DISCRETE2, 7, seed=10 + i) for i in range(2)]
    write(tmp_path / "a.mcap", first)
    write(tmp_path / "b.mcap", second)
    dataset = DemoDataset([tmp_path / "a.mcap", tmp_path / "b.mcap"])
    assert len(dataset) == 5 and dataset.num_transitions == 29
    for read, original in zip(dataset, first + second, strict=True):
        assert_episodes_equal(read, original)
    assert_episodes_equal(dataset[3], second[0])
    assert_episodes_equal(dataset[-1], second[1])


def test_datasets_refuse_mismatched_files(tmp_path) -> None:
    write(tmp_path / "a.mcap", [random_episode(BOX4, DISCRETE2, 5, seed=0)])
    write(tmp_path / "b.mcap", [random_episode(BOX4, gym.spaces.Discrete(3), 5, seed=0)], action_space=gym.spaces.Discrete(3))
    with pytest.raises(DemoFileError, match="b.mcap: action space differs"):
        DemoDataset([tmp_path / "a.mcap", tmp_path / "b.mcap"])


def test_writer_checks_data_against_spaces(tmp_path) -> None:
    episode = random_episode(gym.spaces.Box(-1, 1, (3,), np.float32), DISCRETE2, 5, seed=0)
    with pytest.raises(ImitationError, match=r"observations: got float32\[3\] per row, the space holds float32\[4\]"):
        write(tmp_path / "bad.mcap", [episode])
    assert not (tmp_path / "bad.mcap").exists() and not (tmp_path / "bad.mcap.partial").exists()


def finite_episode(steps: int, seed: int, action_space=DISCRETE2) -> Episode:
    rng = np.random.default_rng(seed)
    actions = rng.integers(0, 2, steps) if action_space is DISCRETE2 else rng.uniform(-1, 1, (steps, *action_space.shape)).astype(action_space.dtype)
    return Episode(observations=rng.normal(size=(steps + 1, 4)).astype(np.float32), actions=actions, rewards=rng.normal(size=steps))


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("observations", np.nan, r"episode 1, step 4: the observation is nan"),
        ("observations", -np.inf, r"episode 1, step 4: the observation is -inf"),
        ("actions", np.inf, r"episode 1, step 4: the action is inf"),
        ("rewards", np.nan, r"episode 1, step 4: the reward is nan"),
    ],
)
def test_writer_refuses_non_finite_values_naming_episode_and_step(tmp_path, field, value, message) -> None:
    box_actions = gym.spaces.Box(-1, 1, (2,), np.float32)
    good, bad = finite_episode(9, 0, box_actions), finite_episode(9, 1, box_actions)
    array = getattr(bad, field).copy()
    array[4, ...] = value
    array[7, ...] = np.nan  # only the first is named
    bad = dataclasses.replace(bad, **{field: array})
    path = tmp_path / "nan.mcap"
    with pytest.raises(ImitationError, match=f"^{path}: {message}; demo files hold finite"):
        write(path, [good, bad], action_space=box_actions, finite_only=True)
    assert list(tmp_path.iterdir()) == [], "nothing half-written"
    # finite_only=False keeps them bit for bit (learners refuse such files when they load them).
    write(path, [good, bad], action_space=box_actions, finite_only=False)
    np.testing.assert_array_equal(getattr(DemoFile(path)[1], field), array)


def test_interrupt_keeps_finished_episodes_other_errors_discard(tmp_path) -> None:
    episode = random_episode(BOX4, DISCRETE2, 5, seed=0)
    with pytest.raises(KeyboardInterrupt):
        with DemoWriter(tmp_path / "k.mcap", finite_only=False, env_id="T", observation_space=BOX4, action_space=DISCRETE2) as writer:
            writer.write(episode)
            raise KeyboardInterrupt
    assert len(DemoFile(tmp_path / "k.mcap", verify=True)) == 1
    with pytest.raises(RuntimeError):
        with DemoWriter(tmp_path / "r.mcap", finite_only=False, env_id="T", observation_space=BOX4, action_space=DISCRETE2) as writer:
            writer.write(episode)
            raise RuntimeError("boom")
    assert list(tmp_path.glob("r.mcap*")) == []


def test_existing_file_is_replaced_only_when_the_new_one_is_complete(tmp_path) -> None:
    path = tmp_path / "f.mcap"
    write(path, [random_episode(BOX4, DISCRETE2, 5, seed=0)])
    before = path.read_bytes()
    with pytest.raises(RuntimeError):
        with DemoWriter(path, finite_only=False, env_id="T", observation_space=BOX4, action_space=DISCRETE2) as writer:
            writer.write(random_episode(BOX4, DISCRETE2, 9, seed=1))
            assert path.read_bytes() == before
            raise RuntimeError("boom")
    assert path.read_bytes() == before


def test_episode_markers_are_plain_json(tmp_path) -> None:
    from mcap.reader import make_reader

    write(tmp_path / "f.mcap", [random_episode(BOX4, DISCRETE2, 5, seed=0)])
    with open(tmp_path / "f.mcap", "rb") as stream:
        markers = [json.loads(message.data) for _, channel, message in make_reader(stream).iter_messages(topics=["/episode"])]
    assert markers[0]["length"] == 5 and markers[0]["index"] == 0


def test_ctrl_c_during_a_write_lands_after_the_episode(tmp_path, monkeypatch) -> None:
    import os
    import signal

    episodes = [random_episode(BOX4, DISCRETE2, 30, seed=i) for i in range(2)]
    original_add = DemoWriter._add
    calls = []

    def interrupting_add(self, topic, log_time, data):
        calls.append(topic)
        if len(calls) == 2:  # in the middle of the second episode's messages
            os.kill(os.getpid(), signal.SIGINT)
        original_add(self, topic, log_time, data)

    with pytest.raises(KeyboardInterrupt):
        with DemoWriter(tmp_path / "c.mcap", finite_only=False, env_id="T", observation_space=BOX4, action_space=DISCRETE2, block_steps=5) as writer:
            writer.write(episodes[0])
            monkeypatch.setattr(DemoWriter, "_add", interrupting_add)
            writer.write(episodes[1])
    demo = DemoFile(tmp_path / "c.mcap", verify=True)
    assert demo.damage is None and len(demo) == 2
    assert_episodes_equal(demo[1], episodes[1])


@pytest.mark.parametrize("compression", ["none", "lz4", "zstd"])
def test_every_compression_round_trips(tmp_path, compression) -> None:
    episodes = [random_episode(BOX4, DISCRETE2, 30 + i, seed=i) for i in range(4)]
    write(tmp_path / "c.mcap", episodes, compression=compression, chunk_size=1500)
    demo = DemoFile(tmp_path / "c.mcap", verify=True)
    for read, original in zip(demo.read_episodes(), episodes, strict=True):
        assert_episodes_equal(read, original)
    assert_episodes_equal(demo[2], episodes[2])


def test_reading_a_subset_decodes_each_chunk_once(tmp_path, monkeypatch) -> None:
    import imitation.data.mcap.records as records

    episodes = [random_episode(BOX4, DISCRETE2, 40, seed=i) for i in range(30)]
    write(tmp_path / "s.mcap", episodes, chunk_size=3000)  # several episodes per chunk
    demo = DemoFile(tmp_path / "s.mcap")
    decoded: list[int] = []
    original = records.decode_chunk

    def counting(record, *args):
        decoded.append(len(record))
        return original(record, *args)

    monkeypatch.setattr(records, "decode_chunk", counting)
    wanted = [3, 4, 5, 17, 29]
    for read, k in zip(demo.read_episodes(wanted), wanted, strict=True):
        assert_episodes_equal(read, episodes[k])
    chunks_needed = {chunk.offset for k in wanted for chunk in demo.chunks_of(demo.episodes[k])}
    assert len(decoded) == len(chunks_needed) < len(demo._index.chunks)


def test_reading_an_absent_episode_raises(tmp_path) -> None:
    write(tmp_path / "f.mcap", [random_episode(BOX4, DISCRETE2, 5, seed=0)])
    with pytest.raises(IndexError, match="out of range"):
        DemoFile(tmp_path / "f.mcap").read_episodes([1])
