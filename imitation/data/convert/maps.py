"""The conversion map: which topics and fields of a bag form the observation, the action and
(optionally) the reward, at what rate, aligned how, on which clock, cut into episodes how.

    rate_hz: 10                 # resampling rate
    time: log                   # log (when the bag recorded it) | header (the message's header.stamp)
    align: hold                 # hold (last value) | interpolate (linear); an entry may override it
    observation:                # concatenated in this order
      - {topic: /turtle1/pose, fields: [x, y, theta, linear_velocity, angular_velocity]}
      - {topic: /camera/image_raw, image: front, size: [480, 640], resize: [96, 128]}  # an image leaf
      - {topic: /scan, fields: [ranges], nonfinite: range_max}      # what inf and NaN stand for
    action:
      - {topic: /turtle1/cmd_vel, fields: [linear.x, angular.z], default: 0, max_age: 1.0}
    reward: {topic: /score, field: data}     # optional; zero rewards without it
    episodes: {split: file}     # file | {split: gap, seconds: 2.0} | {split: topic, topic: /marker}
    env_id: null                # optional gymnasium id the demos belong to

An `image` entry (observation only) makes a sensor_msgs/Image or CompressedImage topic a leaf
of a Dict observation under the key it names, beside `state` (the numeric entries); its frames
are held, never interpolated. `size: [height, width]` refuses frames of any other size;
`resize: [height, width]` stores every frame at that size (`imitation.data.image_resize`: area
averaging), resized once as the bag converts; both are optional.

`nonfinite` says what a numeric entry's NaN and ±inf values stand for, since a demo file holds
finite numbers only (a sensor_msgs/LaserScan reports a beam with no return as +inf, REP 117):
`range_max` (+inf and NaN become the message's own maximum range, -inf its minimum range), a
number (every one becomes it), or `mask` (each becomes 0, and the entry gains a 0/1 column per
value, 1 where the message held a finite reading). Without it a non-finite value is refused.

`load_map` checks the map's own shape (keys, types, values); whether its topics and fields exist
in a bag is checked against the bag in `ros.py`. Errors name the map file and the entry.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from imitation.data.convert.fields import FieldError, parse_field
from imitation.data.convert.yaml_bounded import read_yaml_file
from imitation.errors import ImitationError

# Outside 0.001 Hz (a step per 1000 s) to 10 kHz a rate is a typo, or the map is damaged.
MIN_RATE_HZ, MAX_RATE_HZ = 1e-3, 1e4
MAX_SECONDS = 1e9  # durations (max_age, gaps): beyond 30 years a value is damage, and would overflow nanoseconds
ALIGNMENTS = ("hold", "interpolate")
CLOCKS = ("log", "header")
SPLITS = ("file", "gap", "topic")
_TOP_KEYS = {"rate_hz", "time", "align", "observation", "action", "reward", "episodes", "env_id"}
_ENTRY_KEYS = {"topic", "fields", "field", "align", "default", "max_age", "nonfinite", "image", "size", "resize"}
RANGE_MAX, MASK = "range_max", "mask"  # the named `nonfinite` choices; a number is the third
STATE_KEY = "state"  # the Dict observation's leaf for the numeric entries, beside the images
_IMAGE_KEY = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]{0,63}")
MAX_IMAGE_SIDE = 2**16  # pixels: a larger declared size is a typo


@dataclass(frozen=True)
class Stream:
    """One map entry: these fields of this topic, aligned to the resampling grid.

    `default` fills the grid before the topic's first message and wherever the last message is
    older than `max_age_s` (a command that stopped arriving); without a default the episode
    starts only once every entry has a value."""

    where: str  # e.g. "observation[0]", for error messages
    topic: str
    fields: tuple[str, ...]
    align: str
    default: tuple[float, ...] | None  # one value per field, or one value for all
    max_age_s: float | None
    image: str | None = None  # an image entry: the key of its leaf in the Dict observation
    nonfinite: str | float | None = None  # RANGE_MAX, MASK, a number, or None (refused)
    size: tuple[int, int] | None = None  # an image entry's declared (height, width)
    resize: tuple[int, int] | None = None  # an image entry's stored (height, width), when not its frames' own


@dataclass(frozen=True)
class EpisodeSplit:
    mode: str  # file | gap | topic
    seconds: float | None = None
    topic: str | None = None


@dataclass(frozen=True)
class RecordingMap:
    path: Path
    rate_hz: float
    time: str
    observation: tuple[Stream, ...]
    action: tuple[Stream, ...]
    reward: Stream | None
    episodes: EpisodeSplit
    env_id: str | None
    raw: dict[str, Any]  # the map as written, kept in the demo file's metadata

    @property
    def streams(self) -> tuple[Stream, ...]:
        return self.observation + self.action + ((self.reward,) if self.reward else ())

    @property
    def images(self) -> tuple[Stream, ...]:
        return tuple(stream for stream in self.observation if stream.image is not None)


def load_map(path: str | Path) -> RecordingMap:
    """Read and check a map file; ImitationError names the file and what is wrong."""
    path = Path(path)
    return parse_map(read_yaml_file(path, "map"), path)


def _unplain(value: Any, where: str) -> str | None:
    """What makes a parsed map unusable before it is read field by field: a key that is not
    text (YAML allows `3: x`), or an integer beyond any float (`rate_hz: 1` followed by 5000
    digits, `default: 1e400` written out as an integer)."""
    stack = [(value, where)]
    while stack:
        item, place = stack.pop()
        if isinstance(item, dict):
            for key, sub in item.items():
                if not isinstance(key, str):
                    return f"{place}: keys must be text, got {type(key).__name__} {str(key)[:40]!r}"
                stack.append((sub, f"{place}.{key}" if place != "the map" else key))
        elif isinstance(item, list):
            stack.extend((sub, f"{place}[{i}]") for i, sub in enumerate(item))
        elif isinstance(item, int) and not isinstance(item, bool) and item.bit_length() > 1023:
            return f"{place}: an integer of {item.bit_length()} bits is beyond any float"
    return None


def parse_map(raw: Any, path: Path) -> RecordingMap:
    def fail(message: str) -> ImitationError:
        return ImitationError(f"{path}: {message}")

    if not isinstance(raw, dict):
        raise fail("a map is a YAML mapping with rate_hz, observation and action (see docs/CONVERT.md)")
    problem = _unplain(raw, "the map")
    if problem:
        raise fail(problem)
    unknown = sorted(set(raw) - _TOP_KEYS)
    if unknown:
        raise fail(f"unknown key {unknown[0]!r} (a map has {', '.join(sorted(_TOP_KEYS))})")
    rate = raw.get("rate_hz")
    if (
        isinstance(rate, bool)
        or not isinstance(rate, (int, float))
        or not math.isfinite(rate)
        or not MIN_RATE_HZ <= rate <= MAX_RATE_HZ
    ):
        raise fail(
            f"rate_hz must be a number of samples per second between {MIN_RATE_HZ:g} and {MAX_RATE_HZ:g}, got {str(rate)[:40]}"
        )
    clock = raw.get("time", "log")
    if clock not in CLOCKS:
        raise fail(f"time must be log or header, got {clock!r}")
    align = raw.get("align", "hold")
    if align not in ALIGNMENTS:
        raise fail(f"align must be hold or interpolate, got {align!r}")
    env_id = raw.get("env_id")
    if env_id is not None and (not isinstance(env_id, str) or not env_id):
        raise fail(f"env_id must be a gymnasium id such as CartPole-v1, or null; got {env_id!r}")

    def streams(key: str) -> tuple[Stream, ...]:
        entries = raw.get(key)
        if entries is None or entries == []:
            raise fail(f"no {key}: list at least one {{topic, fields}} entry under '{key}'")
        if not isinstance(entries, list):
            raise fail(f"{key} must be a list of {{topic, fields}} entries")
        return tuple(
            _stream(entry, f"{key}[{i}]", align, fail, images=key == "observation") for i, entry in enumerate(entries)
        )

    observation, action = streams("observation"), streams("action")
    keys = [stream.image for stream in observation if stream.image is not None]
    for stream in observation:
        if stream.image is not None and keys.count(stream.image) > 1:
            raise fail(f"{stream.where} ({stream.topic}): image key {stream.image!r} is taken by another image entry")
    reward = None
    if raw.get("reward") is not None:
        reward = _stream(raw["reward"], "reward", align, fail)
        if len(reward.fields) != 1:
            raise fail("reward: give exactly one field (the reward is one number per step)")
    return RecordingMap(
        path=path,
        rate_hz=float(rate),
        time=clock,
        observation=observation,
        action=action,
        reward=reward,
        episodes=_split(raw.get("episodes", {"split": "file"}), fail),
        env_id=env_id,
        raw=raw,
    )


def _stream(entry: Any, where: str, align: str, fail: Any, *, images: bool = False) -> Stream:
    if not isinstance(entry, dict):
        raise fail(f"{where}: an entry is a mapping such as {{topic: /odom, fields: [twist.twist.linear.x]}}")
    unknown = sorted(set(entry) - _ENTRY_KEYS)
    if unknown:
        raise fail(
            f"{where}: unknown key {unknown[0]!r} (an entry has topic, fields, align, default, max_age, nonfinite; or topic, "
            "image, size, resize)"
        )
    topic = entry.get("topic")
    if not isinstance(topic, str) or not topic:
        raise fail(f"{where}: no topic")
    if "image" in entry:
        return _image_stream(entry, where, topic, fail, images)
    for key in ("size", "resize"):
        if key in entry:
            raise fail(
                f"{where} ({topic}): {key} is for image entries ({{topic: {topic}, image: KEY, {key}: [height, width]}})"
            )
    fields = entry.get("fields", [entry["field"]] if "field" in entry else None)
    if isinstance(fields, str):
        fields = [fields]
    if not isinstance(fields, list) or not fields:
        raise fail(f"{where} ({topic}): no fields: list the numeric fields to take, e.g. fields: [linear.x]")
    for text in fields:
        try:
            parse_field(text)
        except FieldError as error:
            raise fail(f"{where} ({topic}): {error}") from None
    entry_align = entry.get("align", align)
    if entry_align not in ALIGNMENTS:
        raise fail(f"{where} ({topic}): align must be hold or interpolate, got {entry_align!r}")
    default = entry.get("default")
    if default is not None:
        values = default if isinstance(default, list) else [default]
        if not values or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in values):
            raise fail(f"{where} ({topic}): default must be a number or a list of numbers, got {str(default)[:80]}")
        default = tuple(float(v) for v in values)
    max_age = entry.get("max_age")
    if max_age is not None:
        if isinstance(max_age, bool) or not isinstance(max_age, (int, float)) or not 0 < max_age < MAX_SECONDS:
            raise fail(f"{where} ({topic}): max_age must be a positive number of seconds, got {max_age!r}")
        if default is None:
            raise fail(f"{where} ({topic}): max_age needs a default (the value once the last message is too old)")
    nonfinite = _nonfinite(entry.get("nonfinite"), f"{where} ({topic})", entry_align, fail)
    return Stream(
        where, topic, tuple(fields), entry_align, default, float(max_age) if max_age is not None else None, nonfinite=nonfinite
    )


def _nonfinite(value: Any, prefix: str, align: str, fail: Any) -> str | float | None:
    if value is None:
        return None
    if value in (RANGE_MAX, MASK):
        if value == MASK and align == "interpolate":
            raise fail(f"{prefix}: nonfinite: mask gives 0/1 columns, which interpolation would blend; use align: hold")
        return str(value)
    if isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value):
        return float(value)
    raise fail(
        f"{prefix}: nonfinite must be range_max (the message's own range limits), a finite number, or mask (0 and a "
        f"0/1 column per value); got {str(value)[:40]!r}"
    )


def _image_stream(entry: dict[str, Any], where: str, topic: str, fail: Any, allowed: bool) -> Stream:
    """An entry naming a camera topic, e.g. {topic: /camera/image_raw, image: front, size: [480, 640]}."""
    prefix = f"{where} ({topic})"
    if not allowed:
        raise fail(f"{prefix}: images are observations only; move the entry under observation")
    key = entry["image"]
    if not isinstance(key, str) or not _IMAGE_KEY.fullmatch(key) or key == STATE_KEY:
        raise fail(
            f"{prefix}: image must be the key of its leaf in the observation, letters, digits, _ . - (not {STATE_KEY!r}, "
            f"the numeric entries' leaf); got {str(key)[:40]!r}"
        )
    extra = sorted(set(entry) & {"fields", "field", "default", "max_age", "nonfinite"})
    if extra:
        why = {
            "default": "the episode starts at its first frame",
            "max_age": "the episode starts at its first frame",
            "nonfinite": "its pixels are whole numbers",
        }.get(extra[0], "the image is the whole message")
        raise fail(f"{prefix}: an image entry takes no {extra[0]} ({why})")
    if entry.get("align", "hold") != "hold":
        raise fail(f"{prefix}: images are held (the latest frame at each step), never interpolated; drop align")
    sizes: dict[str, tuple[int, int] | None] = {}
    for name in ("size", "resize"):
        size = entry.get(name)
        if size is not None and not (
            isinstance(size, list)
            and len(size) == 2
            and all(isinstance(side, int) and not isinstance(side, bool) and 0 < side <= MAX_IMAGE_SIDE for side in size)
        ):
            raise fail(f"{prefix}: {name} must be [height, width] in pixels, got {str(size)[:40]}")
        sizes[name] = (size[0], size[1]) if size is not None else None
    return Stream(where, topic, (), "hold", None, None, image=key, size=sizes["size"], resize=sizes["resize"])


def _split(spec: Any, fail: Any) -> EpisodeSplit:
    if isinstance(spec, str):
        spec = {"split": spec}
    if not isinstance(spec, dict) or spec.get("split") not in SPLITS:
        raise fail(
            f"episodes must be {{split: file}}, {{split: gap, seconds: S}} or {{split: topic, topic: /marker}}; got {spec!r}"
        )
    mode = spec["split"]
    extra = sorted(set(spec) - {"split", {"gap": "seconds", "topic": "topic"}.get(mode, "split")})
    if extra:
        raise fail(f"episodes: unexpected key {extra[0]!r} for split {mode}")
    if mode == "gap":
        seconds = spec.get("seconds")
        if isinstance(seconds, bool) or not isinstance(seconds, (int, float)) or not 0 < seconds < MAX_SECONDS:
            raise fail(f"episodes: split gap needs seconds: a positive number, got {seconds!r}")
        return EpisodeSplit("gap", seconds=float(seconds))
    if mode == "topic":
        topic = spec.get("topic")
        if not isinstance(topic, str) or not topic:
            raise fail("episodes: split topic needs topic: the marker topic whose messages start episodes")
        return EpisodeSplit("topic", topic=topic)
    return EpisodeSplit("file")
