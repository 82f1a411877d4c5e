"""Damaged and foreign files: one clear DemoFileError, never an uncaught exception, never silently
wrong data; complete episodes before the damage are salvaged."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest
from helpers import assert_episodes_equal, random_episode
from mcap.writer import Writer

from imitation.data.mcap.format import DATASET_METADATA, metadata_crc
from imitation.data.mcap.reader import DemoFile
from imitation.data.mcap.writer import write_episodes
from imitation.errors import DemoFileError

BOX = gym.spaces.Box(-1, 1, (3,), np.float32)
ACTIONS = gym.spaces.Box(-1, 1, (2,), np.float32)
EPISODES = [random_episode(BOX, ACTIONS, 20 + 3 * i, seed=i, terminated=i == 2) for i in range(6)]


@pytest.fixture(scope="module")
def good_file(tmp_path_factory) -> bytes:
    path = tmp_path_factory.mktemp("damage") / "good.mcap"
    write_episodes(path, EPISODES, finite_only=False, env_id="Test-v0", observation_space=BOX, action_space=ACTIONS, durable=True)
    return path.read_bytes()


def read_salvaged(path) -> list:
    demo = DemoFile(path, salvage=True, verify=True)
    episodes = list(demo)
    assert len(episodes) == len(demo)
    for read, original in zip(episodes, EPISODES):
        assert_episodes_equal(read, original)
    return episodes


def test_truncation_at_any_offset_salvages_every_complete_episode(good_file, tmp_path) -> None:
    path = tmp_path / "cut.mcap"
    salvaged_counts = []
    for cut in range(0, len(good_file), 97):
        path.write_bytes(good_file[:cut])
        try:
            salvaged_counts.append(len(read_salvaged(path)))
        except DemoFileError as error:
            assert str(error).startswith(str(path)), error
            salvaged_counts.append(0)
        with pytest.raises(DemoFileError):
            DemoFile(path)
    assert salvaged_counts == sorted(salvaged_counts), "cutting later never salvages less"
    assert max(salvaged_counts) == len(EPISODES)
    # Most of the file is episode data, so some cuts must land between every pair of episodes.
    assert set(range(1, len(EPISODES) + 1)) <= set(salvaged_counts)


def test_bit_flips_are_caught_or_harmless(good_file, tmp_path) -> None:
    rng = np.random.default_rng(0)
    path = tmp_path / "flipped.mcap"
    caught = 0
    for _ in range(400):
        data = bytearray(good_file)
        position = int(rng.integers(len(data)))
        data[position] ^= 1 << int(rng.integers(8))
        path.write_bytes(bytes(data))
        try:
            demo = DemoFile(path, verify=True)
            for read, original in zip(demo, EPISODES, strict=True):
                assert_episodes_equal(read, original)
        except DemoFileError as error:
            caught += 1
            assert "\n" not in str(error) and str(path) in str(error)
            read_salvaged_or_refused(path)
    assert caught > 300, "most bytes of the file are checksummed episode data"


def read_salvaged_or_refused(path) -> None:
    try:
        read_salvaged(path)
    except DemoFileError:
        pass


def test_not_an_mcap_file(tmp_path) -> None:
    for name, content in [("empty.mcap", b""), ("text.mcap", b"hello, world\n" * 10), ("npz.mcap", b"PK\x03\x04" + bytes(100))]:
        (tmp_path / name).write_bytes(content)
        with pytest.raises(DemoFileError, match=f"{name}: not an MCAP file"):
            DemoFile(tmp_path / name, salvage=True)


def test_missing_file(tmp_path) -> None:
    with pytest.raises(DemoFileError, match="nope.mcap: cannot open: No such file"):
        DemoFile(tmp_path / "nope.mcap")


def plain_mcap(path, metadata: dict[str, str] | None) -> None:
    with open(path, "wb") as stream:
        writer = Writer(stream)
        writer.start(profile="", library="test")
        if metadata is not None:
            writer.add_metadata(DATASET_METADATA, {**metadata, "crc32": metadata_crc(metadata)})
        channel = writer.register_channel("/chatter", "json", 0)
        writer.add_message(channel, log_time=1, data=b'{"a": 1}', publish_time=1)
        writer.finish()


def test_mcap_without_our_metadata_is_named_as_such(tmp_path) -> None:
    plain_mcap(tmp_path / "other.mcap", None)
    with pytest.raises(DemoFileError, match="other.mcap: an MCAP file but not an imitation demo file"):
        DemoFile(tmp_path / "other.mcap")


def test_newer_format_version_is_refused(tmp_path) -> None:
    space = json.dumps({"type": "Discrete", "n": 2, "start": 0})
    plain_mcap(tmp_path / "future.mcap", {"format_version": "3", "env_id": "X", "observation_space": space, "action_space": space})
    with pytest.raises(DemoFileError, match="future.mcap: format version 3 is newer than this reader supports"):
        DemoFile(tmp_path / "future.mcap")


def test_ros2_bag_is_not_a_demo_file(testdata) -> None:
    bag = testdata / "ros2" / "replay_testing" / "cmd_vel_only.mcap"
    with pytest.raises(DemoFileError, match="not an imitation demo file"):
        DemoFile(bag)


def test_damage_the_episode_index_never_reads_is_reported_with_every_episode_whole(tmp_path) -> None:
    """A garbled /episode marker (the index intact): `info`'s full scan reports the damage, but
    says that every episode is readable, as training reads them through the index."""
    from helpers import rewrite_messages

    source = tmp_path / "good.mcap"
    write_episodes(source, [random_episode(BOX, ACTIONS, 6, seed=i) for i in range(4)], env_id="T", observation_space=BOX, action_space=ACTIONS, finite_only=False)
    markers = []

    def garble_second_marker(topic, log_time, data):
        if topic == "/episode":
            markers.append(log_time)
            if len(markers) == 2:
                return log_time, b"\xff" + data[1:]
        return log_time, data

    rewrite_messages(source, tmp_path / "marker.mcap", garble_second_marker)
    verified = DemoFile(tmp_path / "marker.mcap", verify=True, salvage=True)
    assert verified.damage and "every episode is whole" in verified.damage
    assert len(verified) == 4 and len(list(DemoFile(tmp_path / "marker.mcap"))) == 4


@pytest.mark.parametrize("k", [486, 780, 908])
def test_info_and_training_agree_on_files_the_fuzzer_found(tmp_path, k: int) -> None:
    """Inputs k of tools/fuzz.py's `cli` target (seed 0): before, `info`'s in-order scan called
    them whole while reading through the episode index (what training does) failed."""
    import importlib.util
    import random
    import sys

    from support import REPO

    spec = importlib.util.spec_from_file_location("imitation_fuzz", REPO / "tools" / "fuzz.py")
    fuzz = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("imitation_fuzz", fuzz)
    spec.loader.exec_module(fuzz)
    seeds = fuzz.cli_seeds(tmp_path)
    rng = random.Random(f"cli:0:{k}")
    path = tmp_path / "input.mcap"
    path.write_bytes(fuzz.cli_mutate(rng.choice(seeds), rng, seeds)["demo.mcap"])
    with pytest.raises(DemoFileError):
        list(DemoFile(path))
    assert DemoFile(path, verify=True, salvage=True).damage is not None


def test_summary_statistics_of_infinite_returns_are_nan_without_a_warning() -> None:
    """`info` on a damaged file whose index claims ±inf returns prints one line, not numpy's warning too."""
    import warnings

    from imitation.data.summary import _stats

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        stats = _stats([1.0, float("inf"), -float("inf")])
    assert np.isnan(stats["mean"]) and np.isnan(stats["std"]) and stats["max"] == float("inf")
