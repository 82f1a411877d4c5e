"""What `imitation info` reports about a demo file: counts, how the end flags were decided, return
and length statistics, spaces, channels, format version, damage (how many complete episodes
were salvaged), and for episodes a person could take over, how often they did (the intervention
rate); for a DAgger run directory, that rate round by round."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from imitation.data.convert.endings import describe_end_flags
from imitation.data.mcap.format import HUMAN_FIELD
from imitation.data.mcap.reader import DemoFile
from imitation.data.mcap.source import is_url
from imitation.data.spaces import describe_space, space_from_json, space_to_json


def _stats(values: list[float]) -> dict[str, float] | None:
    if not values:
        return None
    array = np.asarray(values, dtype=np.float64)
    with np.errstate(all="ignore"):  # a damaged file's ±inf returns give nan, not a warning on stderr
        return {"mean": float(array.mean()), "std": float(array.std()), "min": float(array.min()), "max": float(array.max())}


def summarize(path: str | os.PathLike) -> dict[str, Any]:
    """Open `path`, checking every chunk, and describe it. A damaged file is described by its
    salvageable episodes, with `damage` saying what is wrong (None for a sound file).

    A URL is described from its summary alone, its chunks not fetched (nor checked): only a
    damaged summary makes the whole object be read, to salvage it."""
    demo = DemoFile(path, salvage=True, verify=not is_url(path))
    returns = [facts.episode_return for facts in demo.episodes]
    lengths = [float(facts.length) for facts in demo.episodes]
    return {
        "file": str(demo.path),
        "size_bytes": demo.size,
        "format_version": demo.format_version,
        "env_id": demo.env_id or None,  # JSON null, as in run directories, for demos with no env
        "episodes": len(demo),
        "transitions": demo.num_transitions,
        "terminated": sum(facts.terminated for facts in demo.episodes),
        "truncated": sum(facts.truncated for facts in demo.episodes),
        "end_flags": demo.end_flags,
        "return": _stats(returns),
        "length": _stats(lengths),
        "observation_space": space_to_json(demo.observation_space),
        "action_space": space_to_json(demo.action_space),
        "dt": demo.dt,
        "channels": demo.channels,
        "source": demo.source,
        "creator": demo.creator,
        "damage": demo.damage,
        "salvaged": len(demo) if demo.damage else None,
        "interventions": intervention_rate(demo),
    }


def intervention_rate(demo: DemoFile) -> dict[str, float] | None:
    """How much of the file a person drove: steps under their control, their share of all steps
    (the intervention rate), and the hand-overs to them; None for a file without the channels."""
    if HUMAN_FIELD.topic not in demo.channels:
        return None
    steps = human_steps = takeovers = 0
    for episode in demo:
        steps += len(episode)
        if episode.interventions is not None:
            human_steps += int(episode.interventions.human.sum())
            takeovers += episode.interventions.takeovers
    return {"steps": steps, "human_steps": human_steps, "rate": human_steps / steps if steps else 0.0, "takeovers": takeovers}


def _person_drove(rate: dict[str, float]) -> str:
    return (
        f"person drove {rate['human_steps']} of {rate['steps']} steps ({100 * rate['rate']:.1f} %), "
        f"{rate['takeovers']} take-overs"
    )


def round_files(run_directory: str | os.PathLike) -> list[Path]:
    """A DAgger run directory's round files, in order (empty for any other directory)."""
    return sorted(Path(run_directory).glob("rounds/round-*.mcap"))


def format_rounds(summaries: list[dict[str, Any]]) -> str:
    """One line per DAgger round: episodes, return, and who drove."""
    lines = []
    for summary in summaries:
        rate = summary["interventions"]
        drove = _person_drove(rate) if rate else "no intervention channels"
        mean_return = summary["return"]["mean"] if summary["return"] else float("nan")
        lines.append(f"{Path(summary['file']).name}:  {summary['episodes']} episodes, return {mean_return:.1f};  {drove}")
    return "\n".join(lines)


def format_summary(summary: dict[str, Any]) -> str:
    """The human-readable form of `summarize`'s result."""

    def stats_line(stats: dict[str, float] | None) -> str:
        if stats is None:
            return "-"
        return f"mean {stats['mean']:.2f} ± {stats['std']:.2f}  (min {stats['min']:.2f}, max {stats['max']:.2f})"

    lines = [
        f"file:          {summary['file']} ({summary['size_bytes'] / 1e6:.2f} MB, format version {summary['format_version']})",
        f"env:           {summary['env_id'] or '- (none: recorded without a simulator)'}  (dt {summary['dt']:g} s)",
        f"episodes:      {summary['episodes']}  ({summary['terminated']} terminated, {summary['truncated']} truncated)",
        f"end flags:     {describe_end_flags(summary['end_flags'])}",
        f"transitions:   {summary['transitions']}",
        f"return:        {stats_line(summary['return'])}",
        f"length:        {stats_line(summary['length'])}",
        f"observation:   {describe_space(space_from_json(summary['observation_space']))}",
        f"action:        {describe_space(space_from_json(summary['action_space']))}",
        f"channels:      {', '.join(summary['channels'])}",
        f"source:        {summary['source'] or '-'}  (written by {summary['creator'] or 'unknown'})",
    ]
    if summary["interventions"]:
        rate = summary["interventions"]
        lines.append(f"interventions: a {_person_drove(rate)}")
    if summary["damage"]:
        lines.append(f"DAMAGED:       {summary['damage']}; salvaged {summary['salvaged']} complete episodes")
    return "\n".join(lines)
