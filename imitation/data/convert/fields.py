"""Numeric fields of decoded ROS messages: list them, parse a map's field paths, read them.

Both decoders we use give attribute objects: mcap-ros2-support builds classes with `__slots__`,
rosbags builds dataclasses (with a `__msgtype__` member that is not a field). Arrays arrive as
lists, tuples, bytes, `array.array` or numpy arrays. A field path is written the way ROS tools
write it: `pose.position.x`, `position[1]`, `transforms[0].transform.translation.x`; a path that
ends at a numeric array (`position`) stands for all of its elements.
"""

from __future__ import annotations

import array
import dataclasses
import re
from collections.abc import Iterator, Mapping
from typing import Any

import numpy as np

FieldPath = tuple["str | int", ...]

_PART = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)((?:\[\d+\])*)$")
_INDEX = re.compile(r"\[(\d+)\]")
_SEQUENCES = (list, tuple, bytes, bytearray, array.array, np.ndarray)

# ROS primitives whose every value a float32 holds exactly; every other numeric primitive
# (float64, 32- and 64-bit integers) is kept as float64, exact for 64-bit integers up to 2^53.
_FLOAT32_EXACT = frozenset({"bool", "byte", "char", "int8", "uint8", "int16", "uint16", "float32"})
# rosbags' node kinds in a type's field definitions (rosbags.interfaces.Nodetype).
_BASE, _NAME, _ARRAY, _SEQUENCE = 1, 2, 3, 4


class FieldError(ValueError):
    """A field path that does not name numbers in this message; the text says why."""


def parse_field(text: str) -> FieldPath:
    """`a.b[2].c` → ("a", "b", 2, "c"); FieldError for anything else."""
    if not isinstance(text, str) or not text:
        raise FieldError(f"field {text!r} is not a dotted name such as linear.x")
    path: list[str | int] = []
    for part in text.split("."):
        match = _PART.match(part)
        if match is None:
            raise FieldError(f"field {text!r} is not a dotted name such as linear.x or position[0]")
        path.append(match.group(1))
        path.extend(int(index) for index in _INDEX.findall(match.group(2)))
    return tuple(path)


def format_field(path: FieldPath) -> str:
    text = ""
    for step in path:
        text += f"[{step}]" if isinstance(step, int) else (f".{step}" if text else step)
    return text


def message_fields(value: Any) -> list[str] | None:
    """The field names of a decoded message, or None if `value` is not a message."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        # rosbags declares a message's constants as string-annotated "ClassVar[...]" members,
        # which dataclasses then lists as fields.
        return [f.name for f in dataclasses.fields(value) if not f.name.startswith("__") and "ClassVar" not in str(f.type)]
    slots = getattr(type(value), "__slots__", None)
    if slots and not isinstance(value, _SEQUENCES):
        return [name for name in slots if not name.startswith("_")]
    return None


def numbers(value: Any) -> np.ndarray | None:
    """A numeric scalar or array as float64 values (bools are 0/1), or None if it is not numbers."""
    if isinstance(value, (bool, int, float, np.bool_, np.integer, np.floating)):
        return np.array([value], dtype=np.float64)
    if isinstance(value, (bytes, bytearray)):
        return np.frombuffer(value, dtype=np.uint8).astype(np.float64)
    if isinstance(value, np.ndarray):
        return value.astype(np.float64).reshape(-1) if value.dtype.kind in "biuf" else None
    if isinstance(value, (list, tuple, array.array)) and all(
        isinstance(item, (bool, int, float, np.bool_, np.integer, np.floating)) for item in value
    ):
        return np.asarray(value, dtype=np.float64).reshape(-1)
    return None


def read_field(message: Any, path: FieldPath) -> Any:
    """The value at `path`; FieldError names the step that does not exist."""
    value = message
    for depth, step in enumerate(path):
        where = format_field(path[: depth + 1])
        if isinstance(step, int):
            if not isinstance(value, _SEQUENCES):
                raise FieldError(f"{format_field(path[:depth]) or 'the message'} is not an array, so {where} cannot index it")
            if step >= len(value):
                raise FieldError(f"{where}: index out of range (the array holds {len(value)})")
            value = value[step]
            continue
        names = message_fields(value)
        if names is None or step not in names:
            parent = format_field(path[:depth]) or "the message"
            choices = f" (it has {', '.join(names)})" if names else ""
            raise FieldError(f"{parent} has no field {step!r}{choices}")
        value = getattr(value, step)
    return value


def declared_type(fielddefs: Mapping[str, Any], msgtype: str, text: str) -> str | None:
    """The primitive type (`float64`, `int32`, ...) that the message definitions declare for
    field `text` of `msgtype` (an array's element type), or None if they do not say.
    `fielddefs` is rosbags' form: {msgtype: (constants, [(name, (node kind, detail)), ...])}."""
    try:
        path = parse_field(text)
    except FieldError:
        return None
    node: Any = (_NAME, msgtype)
    for step in path:
        kind, detail = node
        if isinstance(step, int):
            if kind not in (_ARRAY, _SEQUENCE):
                return None
            node = detail[0]
            continue
        definition = fielddefs.get(detail) if kind == _NAME else None
        members = dict(definition[1]) if definition else {}
        if step not in members:
            return None
        node = members[step]
    kind, detail = node
    if kind in (_ARRAY, _SEQUENCE):
        kind, detail = detail[0]
    return str(detail[0]) if kind == _BASE else None


def value_dtype(primitive: str | None) -> np.dtype:
    """The float dtype that holds every value of a ROS primitive exactly: float32 for float32
    and integers of up to 16 bits, float64 for the rest and for fields of unknown type."""
    return np.dtype(np.float32 if primitive in _FLOAT32_EXACT else np.float64)


def resolve_numbers(message: Any, text: str) -> np.ndarray:
    """The numbers field `text` names in `message`; FieldError if it is not numeric."""
    path = parse_field(text)
    value = read_field(message, path)
    values = numbers(value)
    if values is not None:
        return values
    if isinstance(value, str):
        raise FieldError(f"field {text!r} is a string ({value[:40]!r}), not a number")
    names = message_fields(value)
    if names is not None:
        raise FieldError(
            f"field {text!r} is a message, not a number; name one of its fields: {', '.join(f'{text}.{n}' for n in names)}"
        )
    raise FieldError(
        f"field {text!r} holds {type(value).__name__} values, not numbers; index one of its elements, e.g. {text}[0]"
    )


def numeric_fields(message: Any, prefix: str = "", *, every_element: bool = True) -> Iterator[tuple[str, int]]:
    """(field path, number of values) of every numeric leaf of `message`: scalars have 1 value,
    numeric arrays their length; arrays of messages are listed element by element, or by their
    first element only (`every_element=False`: /tf_static's hundreds of transforms read as one)."""
    for name in message_fields(message) or []:
        value = getattr(message, name)
        path = f"{prefix}{name}"
        values = numbers(value)
        if values is not None:
            yield path, len(values)
        elif message_fields(value) is not None:
            yield from numeric_fields(value, path + ".", every_element=every_element)
        elif isinstance(value, (list, tuple)):
            for index, item in enumerate(value if every_element else value[:1]):
                if message_fields(item) is not None:
                    yield from numeric_fields(item, f"{path}[{index}].", every_element=every_element)


def message_arrays(message: Any, prefix: str = "") -> Iterator[tuple[str, int]]:
    """(field path, length) of every array of messages in `message`, looking inside first elements."""
    for name in message_fields(message) or []:
        value = getattr(message, name)
        path = f"{prefix}{name}"
        if numbers(value) is not None:
            continue
        if message_fields(value) is not None:
            yield from message_arrays(value, path + ".")
        elif isinstance(value, (list, tuple)) and value and message_fields(value[0]) is not None:
            yield path, len(value)
            yield from message_arrays(value[0], f"{path}[0].")
