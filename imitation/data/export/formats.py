"""The formats `export --to` writes, one entry each: the exporter and the line that sums up what it
wrote. A new format is an exporter module and one `register(Format(...))`.

Light on purpose (the exporters are imported when they run).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from imitation.errors import ImitationError

Exporter = Callable[..., dict[str, Any]]  # (demo file, destination, *, progress) -> what it wrote


@dataclass(frozen=True)
class Format:
    name: str
    destination: str  # what `--to NAME DEST` names, e.g. DIR
    export: Exporter
    summary: Callable[[dict[str, Any]], str]


FORMATS: dict[str, Format] = {}


def register(format: Format) -> None:
    """Add a format `export --to` writes (a later one of the same name replaces it)."""
    FORMATS[format.name] = format


def format_named(name: str) -> Format:
    if name not in FORMATS:
        choices = " or ".join(f"{known.name} {known.destination}" for known in FORMATS.values())
        raise ImitationError(f"--to {name}: unknown format; use {choices}")
    return FORMATS[name]


def _lerobot(demo: str | os.PathLike, destination: str | os.PathLike, *, progress: bool = True) -> dict[str, Any]:
    from imitation.data.export.lerobot import export_lerobot

    return export_lerobot(demo, destination, progress=progress)


def _foxglove(demo: str | os.PathLike, destination: str | os.PathLike, *, progress: bool = True) -> dict[str, Any]:
    from imitation.data.export.foxglove import export_foxglove

    return export_foxglove(demo, destination, progress=progress)


register(
    Format(
        "lerobot",
        "DIR",
        _lerobot,
        lambda result: (
            f"{result['episodes']} episodes, {result['frames']} frames at {result['fps']} fps (LeRobotDataset v3.0)"
        ),
    )
)
register(
    Format(
        "foxglove",
        "F2.mcap",
        _foxglove,
        lambda result: f"{result['episodes']} episodes, {result['messages']} JSON messages on {', '.join(result['topics'])}",
    )
)
