"""`export --to foxglove`: one JSON message per step with a JSON schema, read back with the
generic `mcap` reader as Foxglove would."""

from __future__ import annotations

import json
from pathlib import Path

import gymnasium as gym
import numpy as np
from mcap.reader import make_reader
from support import DATASETS

from imitation.data.export.foxglove import export_foxglove
from imitation.data.mcap.reader import DemoFile
from imitation.data.mcap.writer import write_episodes
from imitation.data.types import Episode


def read_back(path: Path) -> tuple[dict, list[tuple[str, int, dict]]]:
    with open(path, "rb") as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        schemas = {s.name: s for s in summary.schemas.values()}
        messages = [(channel.topic, message.log_time, json.loads(message.data)) for _, channel, message in reader.iter_messages(log_time_order=False)]
    return schemas, messages


def test_every_step_is_a_json_message(tmp_path: Path) -> None:
    source = DATASETS / "CartPole-v1.mcap"
    result = export_foxglove(source, tmp_path / "steps.mcap", progress=False)
    demo = DemoFile(source)
    schemas, messages = read_back(tmp_path / "steps.mcap")
    step_schema = schemas["imitation.Step"]
    assert step_schema.encoding == "jsonschema"
    schema = json.loads(step_schema.data)
    assert schema["properties"]["observation"] == {"type": "array", "items": {"type": "number"}, "minItems": 4, "maxItems": 4}
    assert schema["properties"]["action"] == {"type": "integer"}
    steps = [(time, body) for topic, time, body in messages if topic == "/step"]
    assert len(steps) == demo.num_transitions + len(demo) == result["messages"] - len(demo)
    episode = demo[0]
    first = [body for _, body in steps if body["episode"] == 0]
    assert len(first) == len(episode) + 1 and first[-1]["final"] and "action" not in first[-1]
    assert first[3]["observation"] == episode.observations[3].tolist() and first[3]["action"] == int(episode.actions[3])
    assert first[-1]["terminated"] == demo.episodes[0].terminated
    times = [time for time, _ in steps]
    assert times == sorted(times) and times[1] - times[0] == round(demo.dt * 1e9)
    assert sum(topic == "/episode" for topic, _, _ in messages) == len(demo)


def test_recordings_keep_their_real_times_and_dict_observations(tmp_path: Path) -> None:
    observations = {"position": np.arange(6, dtype=np.float32).reshape(3, 2), "mode": np.array([0, 1, 1])}
    episode = Episode(observations=observations, actions=np.ones((2, 1), dtype=np.float32), rewards=np.array([0.5, 1.5]),
                      timestamps=np.array([1_000, 5_000, 9_000], dtype=np.int64))
    space = gym.spaces.Dict({"position": gym.spaces.Box(-9, 9, shape=(2,), dtype=np.float32), "mode": gym.spaces.Discrete(2)})
    source = write_episodes(tmp_path / "rec.mcap", [episode], env_id="", observation_space=space,
                            action_space=gym.spaces.Box(-1, 1, shape=(1,), dtype=np.float32))
    export_foxglove(source, tmp_path / "steps.mcap", progress=False)
    _, messages = read_back(tmp_path / "steps.mcap")
    steps = [(time, body) for topic, time, body in messages if topic == "/step"]
    assert [time for time, _ in steps] == [1_000, 5_000, 9_000]
    assert steps[1][1]["observation"] == {"position": [2.0, 3.0], "mode": 1} and steps[1][1]["reward"] == 1.5


def test_camera_leaves_are_copied_as_image_messages_not_json(tmp_path: Path) -> None:
    """A camera is not numbers to plot: its frames go out as the demo file holds them (Foxglove
    image messages on the leaf's own topic, same bytes and log times), and `/step` keeps the rest.
    A 1080p frame as a JSON list took seconds and hundreds of MB per step."""
    rng = np.random.default_rng(0)
    steps = 4
    frames = rng.integers(0, 255, (steps + 1, 6, 8, 3), dtype=np.uint8)
    space = gym.spaces.Dict({"front": gym.spaces.Box(0, 255, (6, 8, 3), np.uint8), "speed": gym.spaces.Box(-9, 9, (1,), np.float32)})
    episode = Episode(observations={"front": frames, "speed": np.arange(steps + 1, dtype=np.float32).reshape(-1, 1)},
                      actions=np.zeros(steps, np.int64), rewards=np.ones(steps), timestamps=np.arange(steps + 1, dtype=np.int64) * 1000 + 50)
    source = write_episodes(tmp_path / "camera.mcap", [episode, episode], env_id="", observation_space=space,
                            action_space=gym.spaces.Discrete(2))
    result = export_foxglove(source, tmp_path / "steps.mcap", progress=False)
    assert result["topics"] == ["/step", "/episode", "/observation/front"]
    with open(source, "rb") as stream:
        stored = [(m.log_time, m.data) for _, c, m in make_reader(stream).iter_messages() if c.topic == "/observation/front"]
    with open(tmp_path / "steps.mcap", "rb") as stream:
        reader = make_reader(stream)
        schemas = {s.name: s for s in reader.get_summary().schemas.values()}
        exported = [(c.topic, m.log_time, m.data) for _, c, m in reader.iter_messages(log_time_order=False)]
    assert json.loads(schemas["imitation.Step"].data)["properties"]["observation"]["properties"].keys() == {"speed"}
    assert schemas["foxglove.CompressedImage"].encoding == "protobuf"
    assert [(time, data) for topic, time, data in exported if topic == "/observation/front"] == stored and len(stored) == 2 * (steps + 1)
    step_messages = [json.loads(data) for topic, _, data in exported if topic == "/step"]
    assert step_messages[2]["observation"] == {"speed": [2.0]}
    assert result["messages"] == len(exported) == 2 * (steps + 1 + 1 + steps + 1)
    times = [time for _, time, _ in exported]
    assert times == sorted(times)  # each frame right after its step


def test_an_observation_that_is_a_camera_alone_leaves_no_observation_in_step(tmp_path: Path) -> None:
    frames = np.zeros((3, 4, 4), np.uint8)
    source = write_episodes(tmp_path / "camera.mcap", [Episode(observations=frames, actions=np.zeros(2, np.int64), rewards=np.zeros(2))],
                            env_id="", observation_space=gym.spaces.Box(0, 255, (4, 4), np.uint8), action_space=gym.spaces.Discrete(2))
    export_foxglove(source, tmp_path / "steps.mcap", progress=False)
    with open(tmp_path / "steps.mcap", "rb") as stream:
        reader = make_reader(stream)
        schema = json.loads(next(s for s in reader.get_summary().schemas.values() if s.name == "imitation.Step").data)
        topics = [c.topic for _, c, _ in reader.iter_messages()]
    assert "observation" not in schema["properties"] and "observation" not in schema["required"]
    assert topics.count("/observation") == 3 and topics.count("/step") == 3
