"""A ROS bag and a conversion map → episodes on a regular time grid.

For each episode span (the whole bag, runs between time gaps, or between marker messages) the
grid starts once every stream without a `default` has a sample and steps at 1/rate_hz up to the
span's last sample, plus one more time one period later, so that the last sampled action is
followed by an observation (the streams' held values). Its T+1 grid times give the T+1
observations, the first T of them the actions, and the reward entry (if any) is read at grid
times 1…T (the reward that follows each action). So a span of S seconds gives floor(S·rate) + 1
steps, and a bag with one message per topic still gives one. Episodes are `truncated`: a
recording stops, it does not reach a terminal state. A span whose grid would hold more than
`grid_steps_per_message` (imitation/limits.py) steps per message of the mapped topics in it is
refused before the grid is allocated: a damaged stamp stretching a few messages over days.

Camera topics (`image` entries, ros_images.py) become uint8 or uint16 (H, W, C) leaves of a Dict
observation beside `state`, the numeric entries: each grid time holds the latest frame at or
before it, decoded once however many steps hold it, and resized once to the entry's `resize`
(or the converter's `image_size`) when it has one (`imitation.data.image_resize`). The steps'
frames together may decode to at most `image_expansion_ratio` times the bag's bytes, counted
(at their stored size) before each episode's are allocated. A camera whose frames are all
JPEG, or all PNG, that decode as they are (ros_images.py) and are not resized keeps them
(`KeptFrames`): a demo file of that image codec stores the bag's bytes.

A demo file holds finite numbers only. An entry's `nonfinite` (maps.py) says what its NaN and
±inf values stand for, and is applied to each message as it is read; the replacements are counted
in a warning. Without it, a non-finite value that reaches the grid is refused, naming the entry,
its topic, the column and the message that holds it.

Values keep their precision: each field's dtype is the float that holds every value of the type
its definition declares (float32 for float32 and small integers, float64 for float64 and wider
integers), and the observation (action) space is float64 as soon as one of its fields is.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from imitation.data.convert.bags import Bag, TopicInfo, extra_bytes_warnings
from imitation.data.convert.converted import Converted
from imitation.data.convert.fields import (
    FieldError,
    message_fields,
    parse_field,
    read_field,
    resolve_numbers,
    value_dtype,
)
from imitation.data.convert.maps import MASK, RANGE_MAX, STATE_KEY, RecordingMap, Stream
from imitation.data.convert.resample import NS, hold_index, regular_grid, sample, split_at_gaps, split_at_markers
from imitation.data.convert.ros_images import Frame, ImageError, decode, frame_of, image_kind
from imitation.data.image_resize import RESIZE_FILTER, resized
from imitation.data.kept_frames import KeptFrames
from imitation.data.types import Episode, Tree
from imitation.errors import ImitationError
from imitation.limits import LIMITS, ImageBudget, input_bytes, over_limit
from imitation.progress import progress_bar

_STAMP = parse_field("header.stamp")

MAX_EPISODE_STEPS = 100_000_000  # a day at 1 kHz: more means damaged timestamps, not a recording
# The fields holding a message's range limits, (minimum, maximum), for `nonfinite: range_max`.
_RANGE_LIMITS = (("range_min", "range_max"), ("min_range", "max_range"))  # sensor_msgs/LaserScan, sensor_msgs/Range


@dataclass
class _Column:
    """One map entry compiled against the bag: its fields' widths and the samples read."""

    stream: Stream
    widths: list[int]
    dtype: np.dtype  # float32 if every field's declared type fits one exactly, else float64
    default: np.ndarray | None
    times: list[int]
    rows: list[np.ndarray]
    bag_path: Path | None = None  # for errors
    limits: tuple[str, str] | None = None  # `nonfinite: range_max`: the message's (minimum, maximum) range fields
    replaced: int = 0  # non-finite values that `nonfinite` replaced

    @property
    def mask(self) -> bool:
        return self.stream.nonfinite == MASK

    @property
    def width(self) -> int:
        """Columns per row: the fields' values, and with `nonfinite: mask` a 0/1 column for each."""
        return sum(self.widths) * (2 if self.mask else 1)

    @property
    def names(self) -> list[str]:
        names = []
        for text, width in zip(self.stream.fields, self.widths):
            base = f"{self.stream.topic}.{text}"
            names += [base] if width == 1 else [f"{base}[{i}]" for i in range(width)]
        return names + [f"finite({name})" for name in names] if self.mask else names

    def add(self, message: Any, time_ns: int, log_ns: int) -> None:
        self.times.append(time_ns)
        self.rows.append(_row(message, self, log_ns))


@dataclass
class _ImageColumn:
    """An image entry compiled against the bag: its frames, checked but not yet decoded."""

    stream: Stream
    kind: str  # ros_images.IMAGE or COMPRESSED
    bag_path: Path
    times: list[int]
    frames: list[Frame]
    labels: list[str]  # where each frame is in the bag, for errors: "frame 3 (logged at … ns)"
    resize: tuple[int, int] | None = None  # the (height, width) frames are stored at, when not their own

    @property
    def key(self) -> str:
        assert self.stream.image is not None  # only image entries become image columns
        return self.stream.image

    def add(self, message: Any, time_ns: int, log_ns: int) -> None:
        label = f"frame {len(self.frames)} (logged at {log_ns} ns)"
        try:
            frame = frame_of(message, self.kind)
        except ImageError as error:
            raise self.error(label, str(error)) from None
        elements = frame.height * frame.width * frame.channels
        if elements > LIMITS.sample_elements:  # before a pixel is decoded
            raise over_limit(
                f"{self.bag_path}: {self.stream.topic} {label}: numbers in one {frame.describe()} frame",
                elements,
                "sample_elements",
            )
        if self.stream.size is not None and (frame.height, frame.width) != self.stream.size:
            height, width = self.stream.size
            raise self.error(label, f"a {frame.describe()} frame; the map's size is [{height}, {width}] ({width}x{height})")
        if self.frames and (frame.shape, frame.dtype) != (self.frames[0].shape, self.frames[0].dtype):
            raise self.error(
                label,
                f"a {frame.describe()} frame, where the topic's first was {self.frames[0].describe()}: a camera whose "
                "resolution changes mid-bag cannot be one observation leaf",
            )
        self.times.append(time_ns)
        self.frames.append(frame)
        self.labels.append(label)

    def error(self, label: str, reason: str) -> ImitationError:
        return ImitationError(f"{self.bag_path}: {self.stream.where} ({self.stream.topic}) {label}: {reason}")

    @property
    def shape(self) -> tuple[int, int, int]:
        """A stored frame's (H, W, C)."""
        first = self.frames[0]
        return (*(self.resize or (first.height, first.width)), first.channels)

    @property
    def frame_bytes(self) -> int:
        return math.prod(self.shape) * self.frames[0].dtype.itemsize

    def space(self) -> gym.spaces.Box:
        dtype = self.frames[0].dtype
        return gym.spaces.Box(0, np.iinfo(dtype).max, shape=self.shape, dtype=dtype)

    def on_grid(self, times: np.ndarray, order: np.ndarray, grid: np.ndarray) -> np.ndarray:
        """The latest frame at or before each grid time, (len(grid), H, W, C); `order` sorts the
        frames by `times`. Each frame is decoded (and resized) once however many steps hold it;
        the rows keep their pictures where every frame has one (KeptFrames)."""
        index = hold_index(times, grid)
        assert index.min() >= 0  # image entries have no default: the grid starts at their first frame
        out = np.empty((len(grid), *self.shape), dtype=self.frames[0].dtype)
        held = [int(order[i]) for i in index]
        for row, k in enumerate(held):
            if row > 0 and k == held[row - 1]:
                out[row] = out[row - 1]
                continue
            try:
                pixels = decode(self.frames[k])
            except ImageError as error:
                raise self.error(self.labels[k], str(error)) from None
            out[row] = resized(pixels, self.resize) if self.resize is not None else pixels
        codecs = {picture for k in held if (picture := self.frames[k].picture) is not None}
        if self.resize is not None or len(codecs) != 1:
            return out
        codec = codecs.pop()
        pictures = {k: bytes(self.frames[k].data) for k in set(held) if self.frames[k].picture == codec}
        return KeptFrames.of(out, codec, [pictures.get(k) for k in held])


def bag_to_episodes(
    bag: Bag, recording_map: RecordingMap, *, progress: bool = True, image_size: tuple[int, int] | None = None
) -> Converted:
    """Read the map's topics from `bag` and resample them into episodes; `image_size` (height,
    width) resizes the frames of every image entry without a `resize` of its own."""
    topics = bag.topics()
    _check_topics(bag, recording_map, topics)
    columns = [_compile(bag, stream, recording_map, image_size) for stream in recording_map.streams]
    by_topic: dict[str, list[_Column | _ImageColumn]] = {}
    for column in columns:
        by_topic.setdefault(column.stream.topic, []).append(column)
    marker_topic = recording_map.episodes.topic
    markers: list[int] = []
    wanted = set(by_topic) | ({marker_topic} if marker_topic else set())
    total = sum(topics[t].count for t in wanted)
    bar = progress_bar(total=total, desc="read", unit="msg", enabled=progress, last_line=False)
    with bar:
        for topic, log_ns, message in bag.messages(sorted(wanted)):
            bar.update()
            time_ns = _time_of(message, log_ns, recording_map, topic)
            if not 0 <= time_ns < 2**63:
                raise ImitationError(
                    f"{bag.path}: a message on {topic} is stamped {time_ns} ns, outside what a timestamp can hold (a damaged "
                    "bag?)"
                )
            if topic == marker_topic:
                markers.append(time_ns)
            for column in by_topic.get(topic, []):
                column.add(message, time_ns, log_ns)

    # (times, rows) of numeric columns, (times, order) of image columns: both sorted by time.
    arrays = {id(c): _sorted_samples(c) for c in columns}
    spans = _spans(recording_map, [arrays[id(c)][0] for c in columns], np.sort(np.asarray(markers, dtype=np.int64)))
    episodes: list[Episode] = []
    warnings = extra_bytes_warnings(bag, sorted(by_topic))
    n_obs = len(recording_map.observation)
    n_act = len(recording_map.action)
    state = [c for c in columns[:n_obs] if isinstance(c, _Column)]
    images = [c for c in columns[:n_obs] if isinstance(c, _ImageColumn)]
    numeric = [c for c in columns if isinstance(c, _Column)]
    acting = [c for c in columns[n_obs : n_obs + n_act] if isinstance(c, _Column)]  # maps.py keeps images to observations
    reward = numeric[-1] if recording_map.reward else None
    observation_dtype = np.result_type(*(c.dtype for c in state)) if state else np.dtype(np.float32)
    action_dtype = np.result_type(*(c.dtype for c in acting))
    observation_space = _observation_space(bag, state, images, observation_dtype)
    # Streams without a default (images never have one) have no value before their first sample: start the grid after it.
    first_values = [int(arrays[id(c)][0][0]) for c in columns if isinstance(c, _ImageColumn) or c.default is None]
    # Frames held over many steps are copied to each: the steps' bytes are counted, not the messages'.
    budget = ImageBudget(str(bag.path), input_bytes(bag.path)) if images else None
    for index, (start, end) in enumerate(spans):
        begin = max([start, *first_values])
        if (end - begin) / NS * recording_map.rate_hz > MAX_EPISODE_STEPS:  # before allocating the grid
            raise ImitationError(
                f"{bag.path}: episode span {index} lasts {(end - begin) / NS:.0f} s, more than {MAX_EPISODE_STEPS} steps at "
                f"{recording_map.rate_hz:g} Hz; are the bag's timestamps damaged, or should the map split episodes?"
            )
        _check_density(bag, recording_map.rate_hz, index, begin, end, {t: arrays[id(cs[0])][0] for t, cs in by_topic.items()})
        grid = regular_grid(begin, end, recording_map.rate_hz)
        if len(grid) == 0:
            warnings.append(
                f"episode span {index} ({start / NS:.3f} s to {end / NS:.3f} s) ends before every stream has a value; skipped"
            )
            continue
        # One period past the last grid time: the last sampled action gets its following observation.
        grid = np.append(grid, grid[-1] + round(NS / recording_map.rate_hz))
        values = {
            id(c): sample(
                *arrays[id(c)],
                grid,
                align=c.stream.align,
                default=c.default,
                max_age_ns=None if c.stream.max_age_s is None else round(c.stream.max_age_s * NS),
            )
            for c in numeric
        }
        for c in numeric:
            _refuse_nonfinite(bag, c, values[id(c)], *arrays[id(c)])
        vector = np.concatenate([values[id(c)] for c in state], axis=1).astype(observation_dtype) if state else None
        observations: Tree
        if images:
            assert budget is not None  # made whenever there are cameras
            budget.take(len(grid) * sum(c.frame_bytes for c in images))
            observations = {c.key: c.on_grid(*arrays[id(c)], grid) for c in images}
            if vector is not None:
                observations = {STATE_KEY: vector, **observations}
        else:
            assert vector is not None  # a map without images has numeric observation entries
            observations = vector
        actions = np.concatenate([values[id(c)] for c in acting], axis=1)[:-1].astype(action_dtype)
        rewards = values[id(reward)][1:, 0] if reward else np.zeros(len(grid) - 1)
        episodes.append(
            Episode(
                observations=observations,
                actions=actions,
                rewards=rewards.astype(np.float64),
                truncated=True,
                timestamps=grid,
                metadata={"span": index},
            )
        )
    if not episodes:
        raise ImitationError(f"{bag.path}: no episode: the mapped topics never all have a value at the same time")
    warnings += [_replaced_warning(c) for c in numeric if c.replaced]
    first = episodes[0]
    assert isinstance(first.actions, np.ndarray)  # built as an array above
    return Converted(
        episodes=episodes,
        observation_space=observation_space,
        action_space=gym.spaces.Box(-np.inf, np.inf, shape=(first.actions.shape[1],), dtype=action_dtype),
        source=f"{bag.format} {bag.path}",
        env_id=recording_map.env_id or "",
        dt=1.0 / recording_map.rate_hz,
        metadata={
            "converter": "ros",
            "bag": str(bag.path),
            "bag_format": bag.format,
            "map": recording_map.raw,
            "observation_names": [n for c in state for n in c.names],
            **({"observation_images": _image_metadata(images)} if images else {}),
            "action_names": [n for c in acting for n in c.names],
            **({"reward_name": reward.names[0]} if reward else {}),
        },
        warnings=warnings,
    )


def _refuse_nonfinite(bag: Bag, column: _Column, on_grid: np.ndarray, times: np.ndarray, rows: np.ndarray) -> None:
    """Refuse a NaN or ±inf that reached the grid (an entry without `nonfinite`), naming the
    column and the first message that holds one in it."""
    bad = ~np.isfinite(on_grid)
    if not bad.any():
        return
    j = int(np.flatnonzero(bad[np.flatnonzero(bad.any(axis=1))[0]])[0])  # the first column of the first step with one
    held = ~np.isfinite(rows[:, j])
    # A non-finite grid value comes from a message's (interpolation too: its neighbours'): there is one.
    first = int(np.flatnonzero(held)[0])
    stream = column.stream
    count = f"; {int(held.sum())} of the topic's {len(rows)} messages hold one there" if held.sum() > 1 else ""
    raise ImitationError(
        f"{bag.path}: {stream.where} ({stream.topic}): column {column.names[j]} is {rows[first, j]} in the message at "
        f"{int(times[first])} ns{count}; a demo file holds finite numbers: say what it stands for with nonfinite: "
        "range_max, a number or mask on the entry (docs/CONVERT.md)"
    )


def _replaced_warning(column: _Column) -> str:
    """What `nonfinite` did to the entry's values, for the conversion's warnings."""
    stream, choice = column.stream, column.stream.nonfinite
    if column.limits is not None:
        became = f"the message's {column.limits[1]} (+inf, NaN) or {column.limits[0]} (-inf)"
    elif choice == MASK:
        became = "0, with 0 in their finite(...) columns"
    else:
        became = f"{choice:g}"
    total = len(column.rows) * sum(column.widths)
    return (
        f"{stream.where} ({stream.topic}): {column.replaced} of the {total} values read were NaN or ±inf; "
        f"nonfinite: {choice} made them {became}"
    )


def _check_density(bag: Bag, rate_hz: float, index: int, begin: int, end: int, times: dict[str, np.ndarray]) -> None:
    """Refuse, before the grid is allocated, an episode span whose grid would hold more than
    `LIMITS.grid_steps_per_message` steps per message of the mapped topics (`times`: each topic's
    sorted sample times) inside it: a damaged stamp that stretches a handful of messages over days
    must not cost gigabytes. The error names the longest silence, where the odd stamp lies."""
    if end < begin:
        return
    steps = math.floor((end - begin) / (NS / rate_hz) + 1e-9) + 1  # as regular_grid counts them
    inside = {topic: t[np.searchsorted(t, begin, "left") : np.searchsorted(t, end, "right")] for topic, t in times.items()}
    messages = sum(len(t) for t in inside.values())
    if steps <= LIMITS.grid_steps_per_message * max(messages, 1):
        return
    names = list(inside)
    every = np.concatenate(list(inside.values()))
    owner = np.concatenate([np.full(len(t), k) for k, t in enumerate(inside.values())])
    order = np.argsort(every, kind="stable")
    every, owner = every[order], owner[order]
    silence = ""
    if len(every) > 1:
        k = int(np.argmax(np.diff(every)))
        silence = (
            f"; the longest silence is {(every[k + 1] - every[k]) / NS:.1f} s, from a message on {names[owner[k]]} stamped "
            f"{every[k] / NS:.3f} s to one on {names[owner[k + 1]]} stamped {every[k + 1] / NS:.3f} s"
        )
    raise over_limit(
        f"{bag.path}: episode span {index}: the {rate_hz:g} Hz grid from {begin / NS:.3f} s to {end / NS:.3f} s would hold "
        f"{steps} steps for {messages} messages on {', '.join(names)}{silence} (a damaged timestamp? a real "
        "silence belongs between episodes: `episodes: {split: gap, seconds: S}`); steps per message",
        math.ceil(steps / max(messages, 1)),
        "grid_steps_per_message",
    )


def _check_topics(bag: Bag, recording_map: RecordingMap, topics: dict[str, TopicInfo]) -> None:
    wanted = [s.topic for s in recording_map.streams] + (
        [recording_map.episodes.topic] if recording_map.episodes.topic else []
    )
    present = sorted(topics)
    if not any(topic in topics for topic in wanted):
        raise ImitationError(
            f"{bag.path}: none of the map's topics ({', '.join(dict.fromkeys(wanted))}) is in this bag; "
            f"it has {_listing(present)} (see `imitation convert {bag.path} --inspect`)"
        )
    for stream in recording_map.streams:
        _check_topic(bag, recording_map, stream.topic, stream.where, topics)
    if recording_map.episodes.topic:
        _check_topic(bag, recording_map, recording_map.episodes.topic, "episodes", topics)


def _check_topic(bag: Bag, recording_map: RecordingMap, topic: str, where: str, topics: dict[str, TopicInfo]) -> None:
    info = topics.get(topic)
    if info is None:
        raise ImitationError(
            f"{recording_map.path}: {where}: topic {topic} is not in {bag.path} (it has {_listing(sorted(topics))})"
        )
    if info.problem:
        raise ImitationError(f"{recording_map.path}: {where}: topic {topic} cannot be read: {info.problem}")
    if info.count == 0:
        raise ImitationError(f"{recording_map.path}: {where}: topic {topic} has no messages in {bag.path}")


def _listing(names: list[str], limit: int = 12) -> str:
    return ", ".join(names[:limit]) + (f", … ({len(names)} topics)" if len(names) > limit else "")


def _compile(
    bag: Bag, stream: Stream, recording_map: RecordingMap, image_size: tuple[int, int] | None = None
) -> _Column | _ImageColumn:
    """Check the entry's fields on the topic's first message and learn their widths."""
    messages = bag.messages([stream.topic])
    try:
        _, _, first = next(messages)
    finally:
        messages.close()
    prefix = f"{recording_map.path}: {stream.where} ({stream.topic})"
    if recording_map.time == "header":
        try:
            read_field(first, _STAMP)
        except FieldError:
            raise ImitationError(f"{prefix}: its messages have no header.stamp; use time: log") from None
    msgtype = bag.topics()[stream.topic].type
    kind = image_kind(msgtype)
    if stream.image is not None:
        if kind is None:
            raise ImitationError(
                f"{prefix}: an image entry needs a sensor_msgs/Image or CompressedImage topic; in {bag.path} it is a {msgtype}"
            )
        return _ImageColumn(stream, kind, bag.path, [], [], [], resize=stream.resize or image_size)
    if kind is not None and any(text.split(".")[0].split("[")[0] == "data" for text in stream.fields):
        raise ImitationError(
            f"{prefix}: a camera topic ({msgtype} in {bag.path}): map its frames as {{topic: {stream.topic}, image: KEY}}"
        )
    widths = []
    for text in stream.fields:
        try:
            width = len(resolve_numbers(first, text))
        except FieldError as error:
            raise ImitationError(f"{prefix}: {error}") from None
        if width == 0:
            raise ImitationError(f"{prefix}: field {text!r} is an empty array in the first message")
        widths.append(width)
    dtype = np.result_type(*(value_dtype(bag.field_type(stream.topic, text)) for text in stream.fields))
    default = None
    if stream.default is not None:
        width = sum(widths)
        if len(stream.default) not in (1, width):
            raise ImitationError(f"{prefix}: default has {len(stream.default)} values; the fields hold {width}")
        default = np.broadcast_to(np.asarray(stream.default, dtype=np.float64), (width,)).copy()
        if stream.nonfinite == MASK:  # before the first message, or once it is stale, there is no reading
            default = np.concatenate([default, np.zeros(width)])
    limits = None
    if stream.nonfinite == RANGE_MAX:
        names = message_fields(first) or []
        limits = next((pair for pair in _RANGE_LIMITS if set(pair) <= set(names)), None)
        if limits is None:
            raise ImitationError(
                f"{prefix}: nonfinite: range_max takes the message's range_max and range_min (sensor_msgs/LaserScan) or "
                f"max_range and min_range (sensor_msgs/Range); a {msgtype} has neither: give a number or mask"
            )
    return _Column(stream, widths, dtype, default, [], [], bag.path, limits)


def _time_of(message: Any, log_ns: int, recording_map: RecordingMap, topic: str) -> int:
    if recording_map.time == "log":
        return log_ns
    try:
        stamp = read_field(message, _STAMP)
    except FieldError:
        if topic == recording_map.episodes.topic:
            return log_ns  # a marker without a header (std_msgs/Empty) marks when it was logged
        raise ImitationError(
            f"{recording_map.path}: topic {topic} has a message without header.stamp; use time: log"
        ) from None
    return int(stamp.sec) * NS + int(getattr(stamp, "nanosec", getattr(stamp, "nsec", 0)))


def _row(message: Any, column: _Column, log_ns: int) -> np.ndarray:
    parts = []
    for text, width in zip(column.stream.fields, column.widths):
        try:
            values = resolve_numbers(message, text)
        except FieldError as error:
            raise ImitationError(f"{column.stream.where} ({column.stream.topic}) at {log_ns} ns: {error}") from None
        if len(values) != width:
            raise ImitationError(
                f"{column.stream.where} ({column.stream.topic}) at {log_ns} ns: field {text!r} held {width} values in the "
                f"first message and {len(values)} now (a variable-length array: index it, e.g. {text}[0])"
            )
        parts.append(values)
    row = np.concatenate(parts)
    return row if column.stream.nonfinite is None else _replace_nonfinite(row, message, column, log_ns)


def _replace_nonfinite(row: np.ndarray, message: Any, column: _Column, log_ns: int) -> np.ndarray:
    """`row` with its NaN and ±inf replaced as the entry's `nonfinite` says (with `mask`, followed
    by a 0/1 column per value); the replacements are counted on `column`."""
    finite = np.isfinite(row)
    if finite.all():
        return np.concatenate([row, np.ones(len(row))]) if column.mask else row
    column.replaced += int(len(row) - finite.sum())
    choice = column.stream.nonfinite
    if column.limits is not None:
        low, high = (float(getattr(message, name)) for name in column.limits)
        if not (math.isfinite(low) and math.isfinite(high)):
            stream = column.stream
            raise ImitationError(
                f"{column.bag_path}: {stream.where} ({stream.topic}) at {log_ns} ns: nonfinite: range_max, but the message's "
                f"{column.limits[0]} is {low:g} and {column.limits[1]} {high:g}; give a number or mask"
            )
        return np.where(finite, row, np.where(np.isneginf(row), low, high))
    if choice == MASK:
        return np.concatenate([np.where(finite, row, 0.0), finite.astype(np.float64)])
    assert isinstance(choice, float)  # maps.py admits range_max, mask or a finite number
    return np.where(finite, row, choice)


def _sorted_samples(column: _Column | _ImageColumn) -> tuple[np.ndarray, np.ndarray]:
    """(times, rows) in time order: header stamps need not arrive in order. An image column's
    frames stay where they are: its second array is the order that sorts them."""
    times = np.asarray(column.times, dtype=np.int64)
    order = np.argsort(times, kind="stable")
    if isinstance(column, _ImageColumn):
        return times[order], order
    rows = np.asarray(column.rows, dtype=np.float64).reshape(len(times), column.width)
    return times[order], rows[order]


def _observation_space(bag: Bag, state: list[_Column], images: list[_ImageColumn], dtype: np.dtype) -> gym.Space:
    """Box(-inf, inf) of the numeric entries; with images, a Dict of `state` and one Box per camera."""
    width = sum(c.width for c in state)
    vector = gym.spaces.Box(-np.inf, np.inf, shape=(width,), dtype=dtype)
    if not images:
        return vector
    leaves: dict[str, gym.Space] = {STATE_KEY: vector} if state else {}
    leaves.update({c.key: c.space() for c in images})
    # The demo file's reader refuses a space whose sample holds more (limits.py): refuse it here, before the grid.
    elements = width + sum(math.prod(c.shape) for c in images)
    if elements > LIMITS.sample_elements:
        raise over_limit(
            f"{bag.path}: numbers in one observation (every camera's pixels and the state)", elements, "sample_elements"
        )
    return gym.spaces.Dict(leaves)


def _image_metadata(images: list[_ImageColumn]) -> dict[str, dict[str, Any]]:
    """Per camera leaf: its topic, what the bag sent (an encoding, or a compressed format) and,
    for a resized one, the frames' own size and the filter."""
    return {
        c.key: {
            "topic": c.stream.topic,
            "sent_as": c.frames[0].source,
            **({"resized_from": [c.frames[0].height, c.frames[0].width], "filter": RESIZE_FILTER} if c.resize else {}),
        }
        for c in images
    }


def _spans(recording_map: RecordingMap, stream_times: list[np.ndarray], markers: np.ndarray) -> list[tuple[int, int]]:
    """(start, end) ns of each episode, before the grid is fitted inside it."""
    every = np.sort(np.concatenate(stream_times))
    start, end = int(every[0]), int(every[-1])
    if recording_map.episodes.mode == "gap":
        assert recording_map.episodes.seconds is not None  # a gap split always has its seconds (maps.py)
        return split_at_gaps(every, round(recording_map.episodes.seconds * NS))
    if recording_map.episodes.mode == "topic":
        return split_at_markers(start, end, markers)
    return [(start, end)]
