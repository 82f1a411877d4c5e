"""Lossless JSON (de)serialisation of gymnasium spaces, and their leaves as (path, dtype, shape).

Supported: Box (any dtype and shape), Discrete, MultiDiscrete, MultiBinary and Dict of these
(nested). The JSON is plain (no NaN/Infinity literals): non-finite bounds are the strings "inf",
"-inf" and "nan", so any JSON parser can read it. Bounds that are the same everywhere are written
as one scalar. The format is specified in docs/FORMAT.md.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from typing import Any

import gymnasium as gym
import numpy as np

from imitation.errors import ImitationError, SpaceError
from imitation.limits import LIMITS, over_limit

LeafPath = tuple[str, ...]


def space_to_json(space: gym.Space) -> dict[str, Any]:
    """A JSON-ready description of `space` from which `space_from_json` rebuilds an equal space."""
    if isinstance(space, gym.spaces.Box):
        return {
            "type": "Box",
            "dtype": np.dtype(space.dtype).name,
            "shape": list(space.shape),
            "low": _bounds_to_json(space.low),
            "high": _bounds_to_json(space.high),
        }
    if isinstance(space, gym.spaces.Discrete):
        return {"type": "Discrete", "n": int(space.n), "start": int(space.start)}
    if isinstance(space, gym.spaces.MultiDiscrete):
        return {
            "type": "MultiDiscrete",
            "dtype": np.dtype(space.dtype).name,
            "nvec": space.nvec.tolist(),
            "start": space.start.tolist(),
        }
    if isinstance(space, gym.spaces.MultiBinary):
        n = space.n
        return {"type": "MultiBinary", "n": list(n) if isinstance(n, (tuple, list, np.ndarray)) else int(n)}
    if isinstance(space, gym.spaces.Dict):
        for key in space.spaces:
            _check_key(key)
        return {"type": "Dict", "spaces": {key: space_to_json(sub) for key, sub in space.spaces.items()}}
    raise SpaceError(
        f"unsupported gymnasium space {type(space).__name__}: use Box, Discrete, MultiDiscrete, MultiBinary or Dict"
    )


# A space read from a file must fit in memory: at most this many numbers in one sample (a 4K RGB
# image is 25 million). Anything larger is refused before anything that size is allocated.


def space_from_json(description: dict[str, Any] | str) -> gym.Space:
    """Rebuild a space from `space_to_json` output (a dict or its JSON text). Anything else,
    however malformed, is a one-line SpaceError."""
    if isinstance(description, str):
        try:
            description = json.loads(description)
        except (ValueError, RecursionError) as error:
            raise SpaceError(f"space description is not JSON ({str(error)[:100]})") from None
    try:
        leaves, elements = _declared(description)
        if leaves > LIMITS.dict_leaves:
            raise over_limit("the space's leaves", leaves, "dict_leaves")
        if elements > LIMITS.sample_elements:
            raise over_limit("numbers per sample of the space", elements, "sample_elements")
        return _space_from_json(description)
    except (SpaceError, ImitationError):
        raise
    except (KeyError, TypeError, ValueError, OverflowError, AttributeError, IndexError, RecursionError) as error:
        raise SpaceError(
            f"malformed space description {short_repr(description)}: {type(error).__name__}: {str(error)[:100]}"
        ) from None


def _declared(description: Any) -> tuple[int, int]:
    """(leaves, numbers per sample) that a description declares, counted before any bound is
    built; what is malformed counts as nothing here and is refused by `_space_from_json`."""
    if not isinstance(description, dict):
        return 1, 0
    kind: Any = description.get("type")  # any JSON value: refused later unless a known name
    if kind == "Dict" and isinstance(description.get("spaces"), dict):
        leaves = elements = 0
        for sub in description["spaces"].values():
            sub_leaves, sub_elements = _declared(sub)
            leaves, elements = leaves + sub_leaves, elements + sub_elements
            if leaves > LIMITS.dict_leaves or elements > LIMITS.sample_elements:
                break
        return leaves, elements
    sizes = {"Box": description.get("shape"), "MultiBinary": description.get("n")}.get(kind, [1])
    if kind == "MultiDiscrete":
        try:
            nvec: Any = description.get("nvec")  # any JSON value (None when missing: shape ())
            sizes = list(np.shape(nvec))
        except ValueError:  # ragged
            return 1, 0
    if isinstance(sizes, int) and not isinstance(sizes, bool):
        sizes = [sizes]
    if (
        not isinstance(sizes, list)
        or len(sizes) > 32
        or not all(isinstance(n, int) and not isinstance(n, bool) and n >= 0 for n in sizes)
    ):
        return 1, 0
    return 1, math.prod(sizes)


def short_repr(value: Any) -> str:
    """repr(value) for an error line, cut to 120 characters."""
    try:
        text = repr(value)
    except RecursionError:
        text = "(nested too deep)"
    return text if len(text) <= 120 else text[:117] + "..."


def _shape(value: Any) -> tuple[int, ...]:
    if (
        not isinstance(value, list)
        or len(value) > 32
        or not all(isinstance(n, int) and not isinstance(n, bool) and n >= 0 for n in value)
    ):
        raise SpaceError(f"space shape must be a list of at most 32 sizes ≥ 0, got {short_repr(value)}")
    if math.prod(value) > LIMITS.sample_elements:
        raise over_limit(f"space shape {value}: numbers per sample", math.prod(value), "sample_elements")
    return tuple(value)


def _dtype(value: Any, kinds: str) -> np.dtype:
    if not isinstance(value, str):
        raise SpaceError(f"space dtype must be a name such as float32, got {short_repr(value)}")
    dtype = np.dtype(value)
    if dtype.kind not in kinds or dtype.itemsize > 8:
        raise SpaceError(f"space dtype {value!r} is not a number type a space can hold")
    return dtype


def _space_from_json(description: Any) -> gym.Space:
    if not isinstance(description, dict):
        raise SpaceError(f"a space description is a JSON object, got {short_repr(description)}")
    kind = description["type"]
    if kind == "Box":
        dtype = _dtype(description["dtype"], "biuf")
        shape = _shape(description["shape"])
        low = _bounds_from_json(description["low"], dtype, shape)
        high = _bounds_from_json(description["high"], dtype, shape)
        return gym.spaces.Box(low=low, high=high, shape=shape, dtype=dtype)
    if kind == "Discrete":
        n, start = int(description["n"]), int(description.get("start", 0))
        if not (1 <= n < 2**63 and -(2**62) <= start < 2**62):
            raise SpaceError(f"Discrete space needs 1 ≤ n < 2^63, got n={n}, start={start}")
        return gym.spaces.Discrete(n, start=start)
    if kind == "MultiDiscrete":
        dtype = _dtype(description.get("dtype", "int64"), "iu")
        nvec = np.asarray(description["nvec"], dtype=dtype)
        _shape(list(nvec.shape))
        starts = np.asarray(description.get("start", np.zeros_like(nvec)), dtype=dtype)
        return gym.spaces.MultiDiscrete(nvec, dtype=dtype, start=starts)
    if kind == "MultiBinary":
        n = description["n"]
        return gym.spaces.MultiBinary(list(_shape(n)) if isinstance(n, list) else _shape([n])[0])
    if kind == "Dict":
        spaces = description["spaces"]
        if not isinstance(spaces, dict):
            raise SpaceError(f"Dict space needs an object of spaces, got {short_repr(spaces)}")
        for key in spaces:
            _check_key(key)
        return gym.spaces.Dict({key: _space_from_json(sub) for key, sub in spaces.items()})
    raise SpaceError(f"unknown space type {short_repr(kind)}")


def space_leaves(space: gym.Space, prefix: LeafPath = ()) -> Iterator[tuple[LeafPath, np.dtype, tuple[int, ...]]]:
    """Each array-valued leaf of `space` as (path, dtype, shape of one sample); Dict spaces nest."""
    if isinstance(space, gym.spaces.Dict):
        for key, sub in space.spaces.items():
            yield from space_leaves(sub, prefix + (key,))
    elif isinstance(space, (gym.spaces.Box, gym.spaces.Discrete, gym.spaces.MultiDiscrete, gym.spaces.MultiBinary)):
        assert space.shape is not None  # set by each of these spaces
        yield prefix, np.dtype(space.dtype), tuple(space.shape)
    else:
        raise SpaceError(f"unsupported gymnasium space {type(space).__name__}")


def spaces_equal(a: gym.Space, b: gym.Space) -> bool:
    """Equal in everything the JSON form records (gymnasium's `==` ignores some dtypes)."""
    return json.dumps(space_to_json(a), sort_keys=True) == json.dumps(space_to_json(b), sort_keys=True)


def spaces_compatible(a: gym.Space, b: gym.Space) -> bool:
    """Same kind, dtype, shape and (for discrete spaces) number of values: a model built for `a`
    can take inputs from `b`. Box bounds may differ."""

    def strip(d: dict[str, Any]) -> dict[str, Any]:
        return {k: (strip(v) if isinstance(v, dict) else v) for k, v in d.items() if k not in ("low", "high")}

    return json.dumps(strip(space_to_json(a)), sort_keys=True) == json.dumps(strip(space_to_json(b)), sort_keys=True)


def check_spaces_fit(owner: str, observation_space: gym.Space, action_space: gym.Space, env: gym.Env, *, where: str) -> None:
    """One-line SpaceError unless a model's (or demos') spaces are compatible with env's, e.g.
    `<where>: the policy's observation space Box(float32, (3,)) does not match the env's ...`."""
    for name, mine, theirs in (
        ("observation", observation_space, env.observation_space),
        ("action", action_space, env.action_space),
    ):
        if not spaces_compatible(mine, theirs):
            raise SpaceError(
                f"{where}: the {owner} {name} space {describe_space(mine)} does not match the env's {describe_space(theirs)}"
            )


def describe_space(space: gym.Space) -> str:
    """A short human-readable form, e.g. `Box(float32, (4,))` or `Discrete(2)`."""
    if isinstance(space, gym.spaces.Box):
        return f"Box({np.dtype(space.dtype).name}, {tuple(space.shape)})"
    if isinstance(space, gym.spaces.Discrete):
        return f"Discrete({space.n})" if space.start == 0 else f"Discrete({space.n}, start={space.start})"
    if isinstance(space, gym.spaces.MultiDiscrete):
        return f"MultiDiscrete({space.nvec.tolist()})"
    if isinstance(space, gym.spaces.MultiBinary):
        return f"MultiBinary({space.n})"
    if isinstance(space, gym.spaces.Dict):
        return "Dict(" + ", ".join(f"{key}: {describe_space(sub)}" for key, sub in space.spaces.items()) + ")"
    return repr(space)


def _check_key(key: Any) -> None:
    if not isinstance(key, str) or not key or "/" in key:
        raise SpaceError(f"Dict space key {key!r} must be a non-empty string without '/' (keys become channel names)")


def _scalar_to_json(value: Any) -> Any:
    if isinstance(value, (np.floating, float)):
        value = float(value)
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return value
    if isinstance(value, (np.bool_, bool)):
        return bool(value)
    return int(value)


def _bounds_to_json(bounds: np.ndarray) -> Any:
    flat = bounds.reshape(-1)
    # Compare as bytes so that NaN == NaN and -0.0 != 0.0: the scalar form must be exact.
    if flat.size > 0 and bool(
        np.all(
            np.ascontiguousarray(flat).view(np.uint8).reshape(flat.size, -1) == np.ascontiguousarray(flat[:1]).view(np.uint8)
        )
    ):
        return _scalar_to_json(flat[0])
    return _nested_to_json(bounds)


def _nested_to_json(array: np.ndarray) -> Any:
    if array.ndim == 0:
        return _scalar_to_json(array[()])
    return [_nested_to_json(row) for row in array]


def _bounds_from_json(value: Any, dtype: np.dtype, shape: tuple[int, ...]) -> np.ndarray:
    def parse(item: Any) -> Any:
        if isinstance(item, list):
            return [parse(x) for x in item]
        if isinstance(item, str):
            return float(item)
        return item

    parsed = parse(value)
    if isinstance(parsed, list):
        return np.asarray(parsed, dtype=dtype).reshape(shape)
    return np.full(shape, parsed, dtype=dtype)
