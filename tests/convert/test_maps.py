"""The conversion map's own checks, field paths, and the resampling arithmetic (no bags needed)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from imitation.data.convert.fields import FieldError, numeric_fields, parse_field, resolve_numbers
from imitation.data.convert.maps import parse_map
from imitation.data.convert.resample import regular_grid, sample, split_at_gaps, split_at_markers
from imitation.errors import ImitationError

MAP = Path("map.yaml")
GOOD = {
    "rate_hz": 10,
    "observation": [{"topic": "/pose", "fields": ["x", "y"]}],
    "action": [{"topic": "/cmd_vel", "fields": ["linear.x", "angular.z"], "default": 0, "max_age": 1.0}],
}


def test_a_good_map_and_its_defaults() -> None:
    parsed = parse_map(GOOD, MAP)
    assert parsed.rate_hz == 10.0 and parsed.time == "log" and parsed.episodes.mode == "file" and parsed.env_id is None
    assert parsed.action[0].default == (0.0,) and parsed.action[0].max_age_s == 1.0 and parsed.observation[0].align == "hold"
    gap = parse_map({**GOOD, "episodes": {"split": "gap", "seconds": 2.0}, "align": "interpolate"}, MAP)
    assert gap.episodes.seconds == 2.0 and gap.observation[0].align == "interpolate"
    assert parse_map({**GOOD, "episodes": {"split": "topic", "topic": "/marker"}}, MAP).episodes.topic == "/marker"


@pytest.mark.parametrize("change, fragment", [
    ({"action": None}, "no action"),
    ({"action": []}, "no action"),
    ({"observation": None}, "no observation"),
    ({"rate_hz": 0}, "rate_hz must be a number of samples per second"),
    ({"rate_hz": "fast"}, "rate_hz"),
    ({"time": "wall"}, "time must be log or header"),
    ({"episodes": {"split": "gap"}}, "split gap needs seconds"),
    ({"episodes": {"split": "weekly"}}, "episodes must be"),
    ({"rates_hz": 5}, "unknown key 'rates_hz'"),
    ({"observation": [{"topic": "/pose"}]}, "observation[0] (/pose): no fields"),
    ({"observation": [{"fields": ["x"]}]}, "observation[0]: no topic"),
    ({"observation": [{"topic": "/pose", "fields": ["x..y"]}]}, "not a dotted name"),
    ({"action": [{"topic": "/cmd", "fields": ["x"], "max_age": 1}]}, "max_age needs a default"),
    ({"reward": {"topic": "/r", "fields": ["a", "b"]}}, "exactly one field"),
])
def test_malformed_maps_name_the_file_and_the_entry(change: dict, fragment: str) -> None:
    with pytest.raises(ImitationError) as error:
        parse_map({**GOOD, **change}, MAP)
    assert str(error.value).startswith("map.yaml: ") and fragment in str(error.value)


class Vector3:
    __slots__ = ["x", "y", "z"]

    def __init__(self, x: float, y: float, z: float) -> None:
        self.x, self.y, self.z = x, y, z


class Twist:  # shaped like mcap-ros2-support's decoded messages
    __slots__ = ["linear", "angular", "frame", "covariance"]

    def __init__(self) -> None:
        self.linear, self.angular = Vector3(1.0, 2.0, 3.0), Vector3(0.0, 0.0, -0.5)
        self.frame, self.covariance = "base_link", [0.1, 0.2, 0.3]


def test_field_paths() -> None:
    assert parse_field("transforms[0].transform.translation.x") == ("transforms", 0, "transform", "translation", "x")
    message = Twist()
    assert resolve_numbers(message, "angular.z").tolist() == [-0.5]
    assert resolve_numbers(message, "covariance").tolist() == [0.1, 0.2, 0.3]
    assert resolve_numbers(message, "covariance[2]").tolist() == [0.3]
    for text, fragment in [("frame", "is a string"), ("linear", "is a message"), ("linear.w", "has no field 'w'"), ("covariance[5]", "out of range")]:
        with pytest.raises(FieldError, match=fragment.replace("[", r"\[")):
            resolve_numbers(message, text)
    assert list(numeric_fields(message)) == [("linear.x", 1), ("linear.y", 1), ("linear.z", 1), ("angular.x", 1), ("angular.y", 1), ("angular.z", 1), ("covariance", 3)]


def test_grid_hold_interpolate_default_and_max_age() -> None:
    grid = regular_grid(0, 1_000_000_000, 4.0)
    assert grid.tolist() == [0, 250_000_000, 500_000_000, 750_000_000, 1_000_000_000]
    times = np.array([100_000_000, 600_000_000])
    values = np.array([[1.0], [3.0]])
    hold = sample(times, values, grid, align="hold", default=np.array([0.0]))
    assert hold[:, 0].tolist() == [0.0, 1.0, 1.0, 3.0, 3.0]
    line = sample(times, values, grid, align="interpolate")
    assert np.isnan(line[0, 0]) and line[1:, 0] == pytest.approx([1.6, 2.6, 3.0, 3.0])
    stale = sample(times, values, grid, align="hold", default=np.array([-1.0]), max_age_ns=300_000_000)
    assert stale[:, 0].tolist() == [-1.0, 1.0, -1.0, 3.0, -1.0]


def test_episode_spans() -> None:
    times = np.array([0, 1, 2, 10, 11, 30]) * 1_000_000_000
    assert split_at_gaps(times, 2_000_000_000) == [(0, 2_000_000_000), (10_000_000_000, 11_000_000_000), (30_000_000_000, 30_000_000_000)]
    assert split_at_markers(0, 30, np.array([10, 20])) == [(0, 9), (10, 19), (20, 30)]
