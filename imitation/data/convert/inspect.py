"""`imitation convert BAG --inspect`: what a bag holds, in the terms a map uses, and a starter map.

For each topic: its type, message count, rate, whether it is latched, and the numeric fields of
its first message (scalars by name, numeric arrays by name with their length; an array of
messages by its first element and its length, so /tf_static's hundred transforms read as one).
Topics that cannot be decoded are listed with the reason and reported as warnings; they never
stop the inspection.

The starter map guesses from message types and rates before names: velocity, joint and
trajectory *commands* are the action, measurements the observation, and logging, transforms,
parameters and one-shot topics (an initial pose, a goal, a latched message) are left out.
`rate_hz` is the command's rate (the fastest command stream's), so that each command is a step;
an observation that would give a new value less than once every `SLOW_STEPS` steps at that rate
(AMCL's pose at 0.6 Hz beside a 20 Hz command) is left out with the reason, unless no faster
observation is left. Without a command with a rate, `rate_hz` is the slowest observation's.
A laser scan (and a sensor_msgs/Range) is offered whole, `ranges` with `nonfinite: range_max`,
as its beams with no return are +inf.
"""

from __future__ import annotations

import re
import textwrap
from pathlib import Path
from typing import Any

import yaml

from imitation.data.convert.bags import Bag, extra_bytes_warnings
from imitation.data.convert.fields import message_arrays, numeric_fields
from imitation.data.convert.maps import MAX_RATE_HZ, MIN_RATE_HZ, RANGE_MAX
from imitation.errors import ImitationError
from imitation.output import create_exclusive, os_error

_FIELD_LIMIT = 200  # per topic, in --json: an image's pixels are one array field anyway
_SHOWN_FIELDS = 24  # per topic, in the text listing and the starter map's comments
_WIDTH = 100  # columns of the text listing's field lines

# What a starter map leaves out, by topic name (any type) and by type (any name), with the reason.
_INFRASTRUCTURE_NAMES = [
    (re.compile(r"^/tf(_static)?$"), "transforms"),
    (re.compile(r"^/rosout(_agg)?$"), "log"),
    (re.compile(r"(^|/)parameter_(events|descriptions|updates)$"), "parameters"),
    (re.compile(r"^/clock$"), "clock"),
    (re.compile(r"^/diagnostics(_agg|_toplevel_state)?$"), "diagnostics"),
    (re.compile(r"^/events/"), "bag events"),
    (re.compile(r"/_service_event$"), "service events"),
    (re.compile(r"/_action/"), "action internals"),
]
_INFRASTRUCTURE_TYPES = {
    "tf2_msgs/TFMessage": "transforms",
    "tf/tfMessage": "transforms",
    "rosgraph_msgs/Log": "log",
    "rcl_interfaces/Log": "log",
    "rcl_interfaces/ParameterEvent": "parameters",
    "dynamic_reconfigure/Config": "parameters",
    "dynamic_reconfigure/ConfigDescription": "parameters",
    "rosgraph_msgs/Clock": "clock",
    "diagnostic_msgs/DiagnosticArray": "diagnostics",
    "actionlib_msgs/GoalStatusArray": "action status",
    "bond/Status": "heartbeats",
}
# Set once or on a click: an initial pose, a goal, a map, the robot's description.
_ONE_SHOT_NAME = re.compile(
    r"(^|/)(initialpose|initial_pose|goal|goal_pose|clicked_point|map|map_metadata|robot_description)$"
)
# Names that say command: a word starting with cmd, command, teleop or joy (cmd_vel, joint_commands,
# arm/cmd, joystick), or the word action(s). Not "control": /husky_velocity_controller/odom is odometry.
_COMMAND_NAME = re.compile(r"(^|[/_])(cmd|command|teleop|joy)|(^|[/_])actions?($|[/_])", re.IGNORECASE)
# Measurements, whatever their topic is called (/husky_velocity_controller/odom is odometry).
_MEASUREMENT_TYPES = {
    "nav_msgs/Odometry",
    "sensor_msgs/Imu",
    "sensor_msgs/NavSatFix",
    "sensor_msgs/MagneticField",
    "sensor_msgs/LaserScan",
    "sensor_msgs/MultiEchoLaserScan",
    "sensor_msgs/PointCloud",
    "sensor_msgs/PointCloud2",
    "sensor_msgs/Image",
    "sensor_msgs/CompressedImage",
    "sensor_msgs/CameraInfo",
    "sensor_msgs/BatteryState",
    "sensor_msgs/Range",
    "sensor_msgs/Temperature",
    "sensor_msgs/FluidPressure",
    "sensor_msgs/Illuminance",
    "sensor_msgs/RelativeHumidity",
    "sensor_msgs/TimeReference",
    "geometry_msgs/PoseWithCovarianceStamped",
    "geometry_msgs/TwistWithCovarianceStamped",
}
_INFRASTRUCTURE_REASONS = {reason for _, reason in _INFRASTRUCTURE_NAMES} | set(_INFRASTRUCTURE_TYPES.values())
_TRAJECTORY_TYPES = {"trajectory_msgs/JointTrajectory", "trajectory_msgs/MultiDOFJointTrajectory"}
# Types that command a robot even on a topic without a command name; the action if nothing else is.
_COMMAND_TYPES = {
    "geometry_msgs/Twist",
    "geometry_msgs/TwistStamped",
    "ackermann_msgs/AckermannDrive",
    "ackermann_msgs/AckermannDriveStamped",
    "sensor_msgs/Joy",
}
_JOY = "sensor_msgs/Joy"
# Commands of a velocity, which the receiving controller stops following when they stop arriving.
_VELOCITY_COMMANDS = _COMMAND_TYPES - {_JOY}
VELOCITY_COMMAND_TIMEOUT = 1.0  # seconds: turtlesim's, and about what velocity controllers use
# Fields a starter leaves out: headers, covariances, times and sequence numbers.
_NOT_A_SIGNAL = re.compile(r"(^|\.)header\.|covariance|(^|\.)(sec|secs|nanosec|nsec|nsecs|seq|stamp)$")
_STARTER_WIDTH = 32  # longest array a starter takes (a 32-joint state); images and covariances are wider
# Range sensors, whose readings are ±inf out of range (REP 117): the field a starter takes, whatever its length.
_RANGE_FIELDS = {"sensor_msgs/LaserScan": "ranges", "sensor_msgs/Range": "range"}
SLOW_STEPS = 10  # an observation slower than one value per this many command steps is left out of a starter


def _short_type(name: str) -> str:
    """pkg/msg/Type and pkg/Type alike, as pkg/Type."""
    parts = name.split("/")
    return f"{parts[0]}/{parts[-1]}" if len(parts) > 1 else name


def inspect_bag(bag: Bag) -> dict[str, Any]:
    """A JSON-ready description of `bag`, with the starter map's guess for each topic
    (`role`: action, observation or None, and `note`: why); undecodable topics appear under
    `warnings` too."""
    topics = bag.topics()
    listing = []
    warnings = []
    for info in topics.values():
        entry: dict[str, Any] = {
            "topic": info.topic,
            "type": info.type,
            "count": info.count,
            "rate_hz": None if info.rate_hz is None else round(info.rate_hz, 3),
            "latched": info.latched,
            "fields": [],
            "arrays": [],
            "problem": info.problem,
        }
        if info.problem:
            warnings.append(f"{info.topic} ({info.type}): skipped: {info.problem}")
        elif info.count:
            messages = bag.messages([info.topic])
            try:
                _, _, first = next(messages)
            finally:
                messages.close()
            fields = list(numeric_fields(first, every_element=False))
            entry["fields"] = [{"field": name, "values": width} for name, width in fields[:_FIELD_LIMIT]]
            entry["fields_left_out"] = max(0, len(fields) - _FIELD_LIMIT)
            entry["arrays"] = [{"field": name, "length": length} for name, length in message_arrays(first)]
        listing.append(entry)
    warnings += extra_bytes_warnings(bag, topics)
    firsts = [i.first_ns for i in topics.values() if i.first_ns is not None]
    lasts = [i.last_ns for i in topics.values() if i.last_ns is not None]
    report = {
        "bag": str(bag.path),
        "format": bag.format,
        "messages": sum(i.count for i in topics.values()),
        "duration_s": (max(lasts) - min(firsts)) / 1e9 if firsts else 0.0,
        "topics": listing,
        "warnings": warnings,
    }
    report["starter"] = _guess(listing)
    return report


def _left_out(entry: dict[str, Any]) -> str | None:
    """Why a starter map leaves this topic out whatever else the bag holds, or None."""
    if entry["problem"]:
        return "cannot decode"
    if not entry["count"]:
        return "no messages"
    for pattern, reason in _INFRASTRUCTURE_NAMES:
        if pattern.search(entry["topic"]):
            return reason
    by_type = _INFRASTRUCTURE_TYPES.get(_short_type(entry["type"]))
    if by_type:
        return by_type
    if not any(f["values"] for f in entry["fields"]):
        return "no numeric fields"
    return None


def _one_shot(entry: dict[str, Any]) -> str | None:
    """Why this topic looks set once rather than streamed, or None."""
    count, rate = entry["count"], entry["rate_hz"] or 0.0
    plural = "s" if count != 1 else ""
    if count < 3:
        return f"one-shot: {count} message{plural}"
    if _ONE_SHOT_NAME.search(entry["topic"]):
        return "one-shot: named like a setting (an initial pose, a goal, a map)"
    if count < 10 and entry.get("latched"):
        return f"one-shot: latched, {count} messages"
    if count < 10 and rate < 1.0:
        return f"one-shot: {count} messages at {rate:.2g} Hz"
    return None


def _guess(listing: list[dict[str, Any]]) -> dict[str, Any]:
    """Set each entry's `role` and `note`; return the starter's rate and where it came from."""
    usable = []
    for e in listing:
        e["role"], e["note"] = None, _left_out(e)
        if e["note"] is None:
            usable.append(e)
    streams = [e for e in usable if _one_shot(e) is None]
    if not streams:  # a bag of single messages (a test bag): use them rather than nothing
        streams = usable
    for e in usable:
        if e not in streams:
            e["note"] = _one_shot(e)

    def command(e: dict[str, Any]) -> bool:
        kind = _short_type(e["type"])
        if kind in _TRAJECTORY_TYPES:
            return True
        return kind not in _MEASUREMENT_TYPES and bool(_COMMAND_NAME.search(e["topic"]))

    actions = [e for e in streams if command(e)]
    if not actions:  # no command by name: a velocity command or a joystick on any topic
        actions = [e for e in streams if _short_type(e["type"]) in _COMMAND_TYPES]
    joysticks = [e for e in actions if _short_type(e["type"]) == _JOY]
    if joysticks and len(joysticks) < len(actions):  # the joystick drives the command already listed
        for e in joysticks:
            actions.remove(e)
            e["note"] = "joystick input behind the command topic"
    for e in streams:
        if e["note"] is None:
            e["role"] = "action" if e in actions else "observation"
    commands = [e for e in actions if e["role"] == "action" and e["rate_hz"]]
    if commands:
        fastest = max(commands, key=lambda e: e["rate_hz"])
        rate = _round_rate(fastest["rate_hz"])
        why = "the command stream" if len(commands) == 1 else "the fastest command stream"
        return {**_rate(rate), "rate_from": fastest["topic"], "rate_why": why, "held": _leave_out_slow(streams, rate)}
    rated = [e for e in streams if e["role"] == "observation" and e["rate_hz"]]
    if not rated:
        return {"rate_hz": 10, "rate_from": None, "rate_why": "no topic has a rate", "held": []}
    slowest = min(rated, key=lambda e: e["rate_hz"])
    return {
        **_rate(_round_rate(slowest["rate_hz"])),
        "rate_from": slowest["topic"],
        "rate_why": "the slowest observation stream",
        "held": [],
    }


def _round_rate(measured: float) -> float:
    """A measured rate as a map writes it: an average over the bag (49.97 Hz is a 50 Hz publisher)
    rounded to an integer within 0.5%, else to 3 digits, and within what a map accepts."""
    rate = float(round(measured)) if abs(measured - round(measured)) <= 0.005 * measured else float(f"{measured:.3g}")
    return min(max(rate, MIN_RATE_HZ), MAX_RATE_HZ)  # damaged timestamps must not make a map that cannot load


def _rate(rate: float) -> dict[str, Any]:
    return {"rate_hz": int(rate) if rate.is_integer() else rate}


def _leave_out_slow(streams: list[dict[str, Any]], rate: float) -> list[str]:
    """Leave out the observations that give a new value less than once every `SLOW_STEPS` steps
    at `rate` (the episode would also wait for their first message), unless none faster is left:
    then they stay, held between their messages, and their topics are returned."""
    observations = [e for e in streams if e["role"] == "observation"]
    slow = [e for e in observations if e["rate_hz"] and e["rate_hz"] * SLOW_STEPS < rate]
    if len(slow) == len(observations):
        return [e["topic"] for e in slow]
    for e in slow:
        e["role"] = None
        e["note"] = (
            f"slow: {e['rate_hz']:.2g} Hz, a new value every {rate / e['rate_hz']:.0f} steps at {rate:g} Hz "
            "(add it back to hold its last value between messages)"
        )
    return []


def _field_names(entry: dict[str, Any], limit: int) -> tuple[list[str], int]:
    """The first `limit` fields as the listing writes them (arrays as name[n]), and how many more."""
    names = [f["field"] if f["values"] == 1 else f"{f['field']}[{f['values']}]" for f in entry["fields"]]
    more = len(names) - limit + entry.get("fields_left_out", 0)
    return names[:limit], max(0, more)


def _describe(entry: dict[str, Any], prefix: str) -> list[str]:
    """The lines under a topic's heading: its fields (wrapped; infrastructure summarised) and arrays."""
    if entry["problem"]:
        return [f"{prefix}cannot decode: {entry['problem']}"]
    if not entry["count"]:
        return []
    names, more = _field_names(entry, _SHOWN_FIELDS)
    arrays = [f"{a['field']} holds {a['length']}" for a in entry.get("arrays", [])]
    if not names:
        return [] if entry.get("note") == "no numeric fields" else [f"{prefix}no numeric fields"]
    if entry.get("role") is None and entry.get("note") in _INFRASTRUCTURE_REASONS:
        total = len(entry["fields"]) + entry.get("fields_left_out", 0)
        text = f"{total} numeric fields, not listed ({entry['note']}; --json lists them)"
        return [prefix + text + (f"; {', '.join(arrays)}" if arrays else "")]
    text = "fields: " + ", ".join(names) + (f" … and {more} more (--json lists them)" if more else "")
    if arrays:
        text += "; arrays of messages listed by their first element: " + ", ".join(arrays)
    return textwrap.wrap(text, _WIDTH, initial_indent=prefix, subsequent_indent=prefix + "  ", break_on_hyphens=False)


def _heading(entry: dict[str, Any]) -> str:
    rate = f"{entry['rate_hz']:.2f} Hz" if entry["rate_hz"] else "-"
    latched = "  latched" if entry.get("latched") else ""
    guess = f"→ {entry['role']}" if entry.get("role") else (f"left out: {entry['note']}" if entry.get("note") else "")
    return f"{entry['topic']}  {entry['type']}  {entry['count']} msgs  {rate}{latched}  [{guess}]"


def format_report(report: dict[str, Any]) -> str:
    """The human-readable form of `inspect_bag`'s result (warnings are printed separately)."""
    lines = [f"{report['bag']}: {report['format']}, {report['messages']} messages over {report['duration_s']:.2f} s"]
    for entry in report["topics"]:
        lines.append("  " + _heading(entry))
        lines += _describe(entry, "      ")
    starter = report.get("starter")
    if starter:
        source = f"{starter['rate_why']}, {starter['rate_from']}" if starter["rate_from"] else starter["rate_why"]
        lines.append(f"A starter map (--write-map) would step at {starter['rate_hz']} Hz ({source}).")
    return "\n".join(lines)


def _starter_fields(entry: dict[str, Any]) -> list[str]:
    """A range sensor's ranges; otherwise scalar and short-array fields, without headers,
    covariances, times and empty arrays."""
    ranges = _RANGE_FIELDS.get(_short_type(entry["type"]))
    if any(f["field"] == ranges and f["values"] for f in entry["fields"]):
        return [str(ranges)]
    fields = [
        f["field"] for f in entry["fields"] if 0 < f["values"] <= _STARTER_WIDTH and not _NOT_A_SIGNAL.search(f["field"])
    ]
    return (fields or [next((f["field"] for f in entry["fields"] if f["values"]), entry["fields"][0]["field"])])[:24]


def _observation_entry(entry: dict[str, Any]) -> dict[str, Any]:
    """A measurement's map entry; a range sensor's out-of-range readings (±inf) are clipped to its limits."""
    observation: dict[str, Any] = {"topic": entry["topic"], "fields": _starter_fields(entry)}
    if observation["fields"] == [_RANGE_FIELDS.get(_short_type(entry["type"]))]:
        observation["nonfinite"] = RANGE_MAX
    return observation


def _action_entry(entry: dict[str, Any]) -> dict[str, Any]:
    """A command topic's map entry. A velocity command that stops arriving means "stop" to the
    controllers that receive it (turtlesim and most velocity controllers time out after about a
    second), so it reverts to 0 once older than `VELOCITY_COMMAND_TIMEOUT`; position targets hold."""
    action = {"topic": entry["topic"], "fields": _starter_fields(entry)}
    if _short_type(entry["type"]) in _VELOCITY_COMMANDS:
        action |= {"default": 0, "max_age": VELOCITY_COMMAND_TIMEOUT}
    return action


def starter_map(report: dict[str, Any]) -> str:
    """YAML text of a map to edit: the guessed action and observation topics with their signal
    fields, `rate_hz` from the command (or the slowest observation); every topic in a comment."""
    starter = report.get("starter") or _guess(report["topics"])
    actions = [e for e in report["topics"] if e.get("role") == "action"]
    observations = [e for e in report["topics"] if e.get("role") == "observation"]
    body = {
        "rate_hz": starter["rate_hz"],
        "time": "log",
        "align": "hold",
        "observation": [_observation_entry(e) for e in observations],
        "action": [_action_entry(e) for e in actions],
        "episodes": {"split": "file"},
        "env_id": None,
    }
    rate_note = f"rate_hz is {starter['rate_hz']} ({starter['rate_why']}" + (
        f", {starter['rate_from']})" if starter["rate_from"] else ")"
    )
    header = [
        f"# Starter map for {report['bag']} ({report['format']}), written by `imitation convert --inspect`.",
        "# Edit it: keep the observation and action entries you want (docs/CONVERT.md describes every key).",
        "# Guessed from message types, names and rates: commands (cmd_vel Twist, joint commands, trajectories)",
        "# are the action, measurements the observation; logging, transforms, parameters and one-shot topics",
        f"# are left out; {rate_note}.",
    ]
    if any("nonfinite" in entry for entry in body["observation"]):
        header.append(
            "# A range sensor's readings out of range are inf (REP 117): nonfinite: range_max clips them to its limits."
        )
    if starter.get("held"):
        header.append(
            f"# {', '.join(starter['held'])}: slower than one value per {SLOW_STEPS} steps, held between messages (no "
            "faster observation)."
        )
    if any((e.get("note") or "").startswith("slow:") for e in report["topics"]):
        header.append(f"# Observations slower than one value per {SLOW_STEPS} steps are left out (the note says so).")
    if any("max_age" in entry for entry in body["action"]):
        header.append(
            f"# Velocity commands revert to 0 after {VELOCITY_COMMAND_TIMEOUT:g} s without a message, as their controllers do."
        )
    if not actions:
        header.append("# No command topic was found: put the topic the demonstrator controlled under action.")
    if not observations:
        header.append("# No observation topic was found: put what the demonstrator saw under observation.")
    header.append("# Topics in the bag (fields marked [n] are arrays of n numbers):")
    for e in report["topics"]:
        header.append(f"#   {_heading(e)}")
        header += _describe(e, "#       ")
    header = [" ".join(line.splitlines()) for line in header]  # a topic name with a line break stays a comment
    return "\n".join(header) + "\n" + yaml.safe_dump(body, sort_keys=False, default_flow_style=None, width=120)


def write_starter_map(report: dict[str, Any], path: str | Path) -> Path:
    """Write `starter_map` to `path`, which must not exist yet (a map may hold hand edits)."""
    path = Path(path)
    if path.exists():
        raise ImitationError(f"--write-map {path}: exists; remove it or choose another name (maps hold hand edits)")
    partial = path.with_name(path.name + ".partial")
    stream = create_exclusive(partial, target=f"--write-map {path}")
    try:
        with stream:
            stream.write(starter_map(report).encode())
        partial.replace(path)
    except OSError as error:
        partial.unlink(missing_ok=True)
        raise os_error(f"--write-map {path}", error) from None
    return path
