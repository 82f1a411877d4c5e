"""`imitation convert BAG --inspect`: what a bag holds, in the terms a map uses, and a starter map.

For each topic: its type, message count, rate, and the numeric fields of its first message
(scalars by name, numeric arrays by name with their length). Topics that cannot be decoded are
listed with the reason and reported as warnings; they never stop the inspection.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import yaml

from imitation.data.convert.bags import Bag
from imitation.data.convert.fields import numeric_fields
from imitation.errors import ImitationError
from imitation.output import create_exclusive, os_error

# Topics a starter map leaves out: logging, transforms, parameters, clocks and services.
_INFRASTRUCTURE = re.compile(r"^/(rosout(_agg)?|tf(_static)?|parameter_events|clock|events/.*)$|/_service_event$|/_action/")
_COMMAND = re.compile(r"cmd|command|action|joy|control|teleop", re.IGNORECASE)
_FIELD_LIMIT = 200  # per topic, in the listing: an image's pixels are one array field anyway


def inspect_bag(bag: Bag) -> dict[str, Any]:
    """A JSON-ready description of `bag`; undecodable topics appear under `warnings` too."""
    topics = bag.topics()
    listing = []
    warnings = []
    for info in topics.values():
        entry: dict[str, Any] = {
            "topic": info.topic,
            "type": info.type,
            "count": info.count,
            "rate_hz": None if info.rate_hz is None else round(info.rate_hz, 3),
            "fields": [],
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
            fields = list(numeric_fields(first))
            entry["fields"] = [{"field": name, "values": width} for name, width in fields[:_FIELD_LIMIT]]
            entry["fields_left_out"] = max(0, len(fields) - _FIELD_LIMIT)
        listing.append(entry)
    firsts = [i.first_ns for i in topics.values() if i.first_ns is not None]
    lasts = [i.last_ns for i in topics.values() if i.last_ns is not None]
    return {
        "bag": str(bag.path),
        "format": bag.format,
        "messages": sum(i.count for i in topics.values()),
        "duration_s": (max(lasts) - min(firsts)) / 1e9 if firsts else 0.0,
        "topics": listing,
        "warnings": warnings,
    }


def format_report(report: dict[str, Any]) -> str:
    """The human-readable form of `inspect_bag`'s result (warnings are printed separately)."""
    lines = [f"{report['bag']}: {report['format']}, {report['messages']} messages over {report['duration_s']:.2f} s"]
    for entry in report["topics"]:
        rate = f"{entry['rate_hz']:.2f} Hz" if entry["rate_hz"] else "-"
        lines.append(f"  {entry['topic']}  {entry['type']}  {entry['count']} msgs  {rate}")
        if entry["problem"]:
            lines.append(f"      cannot decode: {entry['problem']}")
        elif entry["fields"]:
            fields = [f["field"] if f["values"] == 1 else f"{f['field']}[{f['values']}]" for f in entry["fields"]]
            more = f" … and {entry['fields_left_out']} more" if entry.get("fields_left_out") else ""
            lines.append("      fields: " + ", ".join(fields) + more)
        elif entry["count"]:
            lines.append("      no numeric fields")
    return "\n".join(lines)


def starter_map(report: dict[str, Any]) -> str:
    """YAML text of a map to edit: command-like topics as the action, other sensor topics as the
    observation, scalar and short-array fields outside the header; every topic in a comment."""
    usable = [e for e in report["topics"] if e["fields"] and not e["problem"] and not _INFRASTRUCTURE.search(e["topic"])]
    actions = [e for e in usable if _COMMAND.search(e["topic"])]
    observations = [e for e in usable if e not in actions]

    def entry(e: dict[str, Any]) -> dict[str, Any]:
        fields = [f["field"] for f in e["fields"] if not f["field"].startswith("header.") and f["values"] <= 8]
        return {"topic": e["topic"], "fields": (fields or [e["fields"][0]["field"]])[:24]}

    rates = [e["rate_hz"] for e in actions if e["rate_hz"]] or [e["rate_hz"] for e in observations if e["rate_hz"]]
    rate = max(1, round(min(rates))) if rates else 10
    body = {
        "rate_hz": rate,
        "time": "log",
        "align": "hold",
        "observation": [entry(e) for e in observations],
        "action": [entry(e) for e in actions],
        "episodes": {"split": "file"},
        "env_id": None,
    }
    header = [
        f"# Starter map for {report['bag']} ({report['format']}), written by `imitation convert --inspect`.",
        "# Edit it: keep the observation and action entries you want (docs/CONVERT.md describes every key).",
        "# Guessed: topics named like commands are the action; rate_hz is the slowest of their rates.",
    ]
    if not actions:
        header.append("# No command-like topic was found: put the topic the demonstrator controlled under action.")
    header.append("# Topics in the bag (fields marked [n] are arrays of n numbers):")
    for e in report["topics"]:
        note = (
            "cannot decode"
            if e["problem"]
            else ", ".join(f["field"] if f["values"] == 1 else f"{f['field']}[{f['values']}]" for f in e["fields"][:40])
            or "no numeric fields"
        )
        header.append(f"#   {e['topic']} ({e['type']}, {e['count']} msgs): {note}")
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
