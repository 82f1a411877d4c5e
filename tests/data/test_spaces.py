"""Space JSON round trips: every supported space and dtype comes back equal, via real JSON text."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from imitation.data.spaces import describe_space, space_from_json, space_leaves, space_to_json, spaces_equal
from imitation.errors import SpaceError

BOX_DTYPES = [np.float16, np.float32, np.float64, np.int8, np.int16, np.int32, np.int64, np.uint8, np.uint16, np.uint32, np.uint64]
shapes = st.lists(st.integers(1, 4), min_size=0, max_size=3).map(tuple)


@st.composite
def boxes(draw: st.DrawFn) -> gym.spaces.Box:
    dtype = np.dtype(draw(st.sampled_from(BOX_DTYPES)))
    shape = draw(shapes)
    if dtype.kind == "f":
        low = draw(st.sampled_from([-np.inf, -1.0, 0.0, -2.5]))
        high = draw(st.sampled_from([np.inf, 1.0, 3.25]))
        per_element = draw(st.booleans())
        if per_element and shape:
            values = np.linspace(-1, 1, int(np.prod(shape)), dtype=dtype).reshape(shape)
            return gym.spaces.Box(low=values - 1, high=values + 1, dtype=dtype)
        return gym.spaces.Box(low=low, high=high, shape=shape, dtype=dtype)
    info = np.iinfo(dtype)
    low = draw(st.sampled_from([int(info.min), 0]))
    high = draw(st.sampled_from([int(info.max), 10]))
    return gym.spaces.Box(low=low, high=high, shape=shape, dtype=dtype)


leaf_spaces = st.one_of(
    boxes(),
    st.builds(gym.spaces.Discrete, st.integers(1, 1000), start=st.integers(-5, 5)),
    st.builds(lambda nvec: gym.spaces.MultiDiscrete(nvec), st.lists(st.integers(1, 9), min_size=1, max_size=4)),
    st.builds(lambda n: gym.spaces.MultiBinary(n), st.one_of(st.integers(1, 8), st.lists(st.integers(1, 3), min_size=1, max_size=2))),
)
all_spaces = st.recursive(
    leaf_spaces,
    lambda children: st.dictionaries(st.sampled_from(["a", "b", "pos", "img"]), children, min_size=1, max_size=3).map(gym.spaces.Dict),
    max_leaves=5,
)


@settings(max_examples=200, deadline=None)
@given(all_spaces)
def test_every_space_survives_json_text(space: gym.Space) -> None:
    restored = space_from_json(json.dumps(space_to_json(space), allow_nan=False))
    assert spaces_equal(restored, space)
    assert type(restored) is type(space)
    for (path_a, dtype_a, shape_a), (path_b, dtype_b, shape_b) in zip(space_leaves(space), space_leaves(restored), strict=True):
        assert (path_a, dtype_a, shape_a) == (path_b, dtype_b, shape_b)
    if isinstance(space, gym.spaces.Box):
        np.testing.assert_array_equal(restored.low, space.low)
        np.testing.assert_array_equal(restored.high, space.high)


def test_classic_control_spaces_round_trip() -> None:
    for env_id in ["CartPole-v1", "MountainCar-v0", "Pendulum-v1", "Acrobot-v1"]:
        env = gym.make(env_id)
        for space in (env.observation_space, env.action_space):
            assert space_from_json(space_to_json(space)) == space


def test_infinite_bounds_are_plain_json_strings() -> None:
    text = json.dumps(space_to_json(gym.spaces.Box(-np.inf, np.inf, (2,), np.float32)), allow_nan=False)
    assert '"-inf"' in text and '"inf"' in text


def test_float32_bounds_are_exact() -> None:
    space = gym.spaces.Box(low=np.float32(0.1), high=np.float32(1 / 3), shape=(3,), dtype=np.float32)
    restored = space_from_json(json.loads(json.dumps(space_to_json(space))))
    assert restored.low.tobytes() == space.low.tobytes() and restored.high.tobytes() == space.high.tobytes()


def test_unsupported_space_and_bad_keys_are_refused() -> None:
    with pytest.raises(SpaceError, match="unsupported"):
        space_to_json(gym.spaces.Text(5))
    with pytest.raises(SpaceError, match="without '/'"):
        space_to_json(gym.spaces.Dict({"a/b": gym.spaces.Discrete(2)}))
    with pytest.raises(SpaceError, match="unknown space type"):
        space_from_json({"type": "Graph"})


def test_describe_space_is_short() -> None:
    assert describe_space(gym.spaces.Discrete(2)) == "Discrete(2)"
    assert describe_space(gym.spaces.Box(0, 1, (4,), np.float32)) == "Box(float32, (4,))"
