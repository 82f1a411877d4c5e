"""What an env's step infos say of a task beyond its return, measured per episode and averaged
over the episodes `evaluate_policy` plays: whether it succeeded (`is_success` at any step, the key
gymnasium-robotics, Meta-World and gym-pusht set) and, where an env reports it, the largest
`coverage` it reached (PushT: the fraction of the goal the block covers; success is coverage
above 0.95). A new measure is one `InfoMeasure` in `MEASURES`."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class InfoMeasure:
    """An info key, how an episode's values reduce to one number, and the name of their mean over episodes."""

    key: str
    reduce: Callable[[list[float]], float]
    name: str


MEASURES = (
    InfoMeasure("is_success", lambda values: float(any(values)), "success_rate"),
    InfoMeasure("coverage", max, "mean_max_coverage"),
)


class EpisodeMeasures:
    """The measures of one episode, fed its step infos."""

    def __init__(self) -> None:
        self.values: dict[str, list[float]] = {}

    def step(self, info: Mapping[str, Any]) -> None:
        for measure in MEASURES:
            value = info.get(measure.key)
            if isinstance(value, (bool, int, float, np.bool_, np.integer, np.floating)):
                self.values.setdefault(measure.key, []).append(float(value))

    def result(self) -> dict[str, float]:
        """Each measure the episode's infos held, reduced: {info key: value}."""
        return {measure.key: measure.reduce(self.values[measure.key]) for measure in MEASURES if measure.key in self.values}


def averaged(episodes: Iterable[dict[str, float]]) -> dict[str, Any]:
    """The mean of each measure every episode has (`success_rate`, `mean_max_coverage`), and its per-episode values."""
    episodes = list(episodes)
    out: dict[str, Any] = {}
    for measure in MEASURES:
        if episodes and all(measure.key in episode for episode in episodes):
            values = [episode[measure.key] for episode in episodes]
            out[measure.name] = float(np.mean(values))
            out[f"episode_{measure.key}"] = values
    return out


def measures_line(result: Mapping[str, Any]) -> str | None:
    """The task's measures in `evaluate_policy`'s result as a line ("success rate 0.64, mean max
    coverage 0.912"), None when the env reports none."""
    parts = [
        f"{measure.name.replace('_', ' ')} {result[measure.name]:.3f}"
        for measure in MEASURES
        if isinstance(result.get(measure.name), float)
    ]
    return ", ".join(parts) or None
