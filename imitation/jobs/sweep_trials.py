"""A sweep's own record of its trials, `OUT/trials.json`: what a rerun continues from.

Continuing a sweep never reads Ray Tune's experiment state: Tune restores it by unpickling, and
no file may run code. Instead the sweep names every trial itself and keeps, as JSON, each
trial's flags' values, how it ended and the figures it reported; each trial's progress is its
run directory, OUT/runs/TRIAL, with its checkpoint (safetensors and JSON) while it runs.

Random search is planned whole before the first trial starts: every trial's values are drawn
here from the sweep's seed, so a rerun runs exactly the trials that have not ended, under the
names and with the values they had. Optuna's trials are recorded as Tune starts them; a rerun
runs the unended ones again with their values, then tells Optuna the results of the ended ones
before it samples the rest.
"""

from __future__ import annotations

import itertools
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from imitation.errors import ImitationError
from imitation.jobs.sweep_config import Distribution, Scalar, SweepConfig
from imitation.jobs.sweep_results import FAILED, FINISHED, STOPPED, UNFINISHED, TrialOutcome
from imitation.output import writing
from imitation.runs import write_json

TRIALS_FILE = "trials.json"
ENDED = (FINISHED, STOPPED)  # a rerun keeps these; it runs failed and unfinished trials again
_STATUSES = (FINISHED, STOPPED, FAILED, UNFINISHED)


def plan_trials(config: SweepConfig) -> list[TrialOutcome]:
    """Random search's every trial, named trial-000, trial-001, ...: `trials` samples of the
    space, each running every combination of the grid flags' values (as Tune's grid search
    does), the other flags drawn from a generator seeded with the sweep's seed."""
    generator = np.random.default_rng(config.seed)
    grid = [key for key, distribution in config.space.items() if distribution.kind == "grid"]
    combinations = list(itertools.product(*(config.space[key].values for key in grid)))
    width = max(3, len(str(config.total_trials - 1)))
    planned: list[TrialOutcome] = []
    for _ in range(config.trials):
        for combination in combinations:
            fixed = dict(zip(grid, combination))
            params = {
                key: fixed[key] if key in fixed else _draw(distribution, generator)
                for key, distribution in config.space.items()
            }
            planned.append(TrialOutcome(trial=f"trial-{len(planned):0{width}d}", params=params, status=UNFINISHED))
    return planned


def _draw(distribution: Distribution, generator: np.random.Generator) -> Scalar:
    kind, values = distribution.kind, distribution.values
    if kind == "choice":
        return values[int(generator.integers(len(values)))]
    low, high = (float(value) for value in values)
    if kind == "randint":
        return int(generator.integers(int(low), int(high) + 1))  # both ends included, as the config says
    if kind == "loguniform":
        return min(max(math.exp(generator.uniform(math.log(low), math.log(high))), low), high)  # exp(log x) may round past x
    return float(generator.uniform(low, high))


def _within(distribution: Distribution, value: Any) -> bool:
    """Whether `value` is one a trial of `distribution` can take."""
    if distribution.kind in ("choice", "grid"):
        return any(type(value) is type(choice) and value == choice for choice in distribution.values)
    if isinstance(value, bool) or not isinstance(value, int | float):
        return False
    low, high = distribution.values
    return float(low) <= value <= float(high) and (distribution.kind != "randint" or isinstance(value, int))


class SweepTrials:
    """The trials of one sweep folder, saved to OUT/trials.json (replaced in one rename) at every change."""

    def __init__(self, out: Path, records: list[TrialOutcome]) -> None:
        self.path = out / TRIALS_FILE
        self.records = {record.trial: record for record in records}

    @classmethod
    def open(cls, out: Path, config: SweepConfig, *, resumed: bool) -> SweepTrials:
        """A new sweep's trials (random search planned whole), or those a rerun continues."""
        path = out / TRIALS_FILE
        if resumed and path.is_file():
            return cls(out, _read(path, config))
        if resumed and (out / "runs").is_dir() and any((out / "runs").iterdir()):
            raise ImitationError(
                f"{out}: holds a sweep without {TRIALS_FILE} (one from an earlier version, whose state was Ray Tune's pickle, "
                "which is never read); start it again with a new --out"
            )
        trials = cls(out, plan_trials(config) if config.search == "random" else [])
        trials.save()
        return trials

    def started(self, name: str, params: dict[str, Any]) -> TrialOutcome:
        """The record of trial `name` (a new one for a trial Optuna sampled), running again."""
        record = self.records.setdefault(name, TrialOutcome(trial=name, params=params, status=UNFINISHED))
        record.status, record.error = UNFINISHED, ""
        self.save()
        return record

    def unended(self) -> list[str]:
        return [name for name, record in self.records.items() if record.status not in ENDED]

    def ended(self) -> list[TrialOutcome]:
        return [record for record in self.records.values() if record.status in ENDED]

    def save(self) -> None:
        entries = [
            {"trial": r.trial, "params": r.params, "status": r.status, "metric": r.metric, "steps": r.steps, "error": r.error}
            for r in self.records.values()
        ]
        with writing(self.path):
            write_json(self.path, {"trials": entries})


def _read(path: Path, config: SweepConfig) -> list[TrialOutcome]:
    """The records of `path`, each checked against the sweep: a damaged or edited file is one line."""
    try:
        document = json.loads(path.read_text())
        entries = document["trials"]
        if not isinstance(entries, list):
            raise TypeError("trials is not a list")
        return [_record(entry, config) for entry in entries]
    except (OSError, ValueError, KeyError, TypeError) as error:
        raise ImitationError(f"{path}: unreadable ({error}); it was not written by this sweep, or was edited") from None


def _record(entry: Any, config: SweepConfig) -> TrialOutcome:
    if not isinstance(entry, dict):
        raise TypeError(f"a trial is {type(entry).__name__}, not an object")
    name, params, status = entry.get("trial"), entry.get("params"), entry.get("status")
    if not (isinstance(name, str) and name.isprintable() and "/" not in name and name not in ("", ".", "..")):
        raise ValueError(f"trial name {str(name)[:60]!r} is not a folder name")
    if not (isinstance(params, dict) and set(params) == set(config.space)):
        raise ValueError(f"trial {name}: its values are not those of the sweep's space ({', '.join(config.space)})")
    for key, value in params.items():
        if not _within(config.space[key], value):
            raise ValueError(f"trial {name}: {key} {str(value)[:60]!r} is outside the sweep's space")
    if status not in _STATUSES:
        raise ValueError(f"trial {name}: unknown status {str(status)[:60]!r}")
    metric, steps, error = entry.get("metric"), entry.get("steps"), entry.get("error", "")
    if not (metric is None or isinstance(metric, int | float)) or not (steps is None or isinstance(steps, int)):
        raise TypeError(f"trial {name}: metric and steps must be numbers")
    return TrialOutcome(trial=name, params=params, status=status, metric=metric, steps=steps, error=str(error))
