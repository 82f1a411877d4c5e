"""What a sweep leaves: the results table (CSV and markdown) and `best/`, a copy of the best
finished trial's run directory.

A copy, not a link: the sweep's folder can be moved or archived and `best/` still holds the run.
Only a finished trial can be the best: one stopped early (ASHA) or failed leaves no finished
run directory, and its figure comes from fewer steps than the others'.
"""

from __future__ import annotations

import csv
import io
import math
import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from imitation.errors import ImitationError
from imitation.output import replace_directory, writing
from imitation.runs import METRICS_FILE, PROGRESS_FILE

FINISHED = "finished"
STOPPED = "stopped early"
FAILED = "error"
UNFINISHED = "not finished"
RUNS_DIR = "runs"
BEST_DIR = "best"
TABLE_CSV = "results.csv"
TABLE_MARKDOWN = "results.md"


@dataclass
class TrialOutcome:
    """One trial as the table shows it: its flags' values, its result (the metric in the sweep's
    scope), the steps it ran, how it ended and its run directory (finished trials)."""

    trial: str
    params: dict[str, Any]
    status: str  # FINISHED, STOPPED, FAILED or UNFINISHED
    metric: float | None = None
    steps: int | None = None
    error: str = ""
    run: Path | None = None
    best: bool = False


def read_rows(run: Path) -> list[dict[str, float]]:
    """The rows a run logged (its progress.csv), as numbers; empty when there is none."""
    try:
        with open(run / PROGRESS_FILE, newline="") as stream:
            return [{key: _float(value) for key, value in row.items()} for row in csv.DictReader(stream)]
    except FileNotFoundError:
        return []


def finished_run(run: Path) -> bool:
    """Whether `run` is a finished run directory (moved into place with its metrics)."""
    return (run / METRICS_FILE).is_file()


def scoped(values: list[float], *, mode: str, scope: str) -> float | None:
    """A trial's result from its values of the metric: the last finite one, or the best."""
    finite = [value for value in values if math.isfinite(value)]
    if not finite:
        return None
    if scope == "last":
        return finite[-1]
    return min(finite) if mode == "min" else max(finite)


def run_result(run: Path, *, command: str, metric: str, mode: str, scope: str) -> tuple[float, int]:
    """A finished run's result (its metric in the sweep's scope) and the steps it ran."""
    rows = read_rows(run)
    value = scoped([row.get(metric, math.nan) for row in rows], mode=mode, scope=scope)
    if value is None:
        raise ImitationError(f"{command}: no finite {metric} in any of the {len(rows)} rows of {run}")
    return value, len(rows)


def choose_best(outcomes: list[TrialOutcome], *, mode: str) -> TrialOutcome | None:
    """The finished trial with the best result (the first of equals), marked `best`."""
    candidates = [outcome for outcome in outcomes if outcome.status == FINISHED and outcome.metric is not None]
    if not candidates:
        return None
    sign = 1.0 if mode == "min" else -1.0
    best = min(candidates, key=lambda outcome: sign * (outcome.metric or 0.0))
    best.best = True
    return best


def write_results(out: Path, outcomes: list[TrialOutcome], *, metric: str, heading: str) -> str:
    """results.csv and results.md in `out`, each replaced in one rename; the markdown text."""
    params = list(dict.fromkeys(key for outcome in outcomes for key in outcome.params))
    header = ["trial", *params, metric, "steps", "status", "run"]
    rows = [
        [
            outcome.trial,
            *(outcome.params.get(key, "") for key in params),
            "" if outcome.metric is None else outcome.metric,
            "" if outcome.steps is None else outcome.steps,
            _status(outcome),
            "" if outcome.run is None else os.path.relpath(outcome.run, out),
        ]
        for outcome in outcomes
    ]
    text = io.StringIO()
    csv.writer(text).writerows([header, *rows])
    _replace(out / TABLE_CSV, text.getvalue())
    shown = [[_cell(value) for value in row] for row in rows]
    for outcome, row in zip(outcomes, shown):
        if outcome.best:
            row[0] += " (best)"
    markdown = "\n".join([heading, "", _markdown_table(header, shown), ""])
    _replace(out / TABLE_MARKDOWN, markdown)
    return markdown


def copy_best(out: Path, best: TrialOutcome) -> Path:
    """`out/best`: a copy of the best trial's run directory, put in place in one step."""
    assert best.run is not None  # only finished trials are chosen
    target, fresh = out / BEST_DIR, out / (BEST_DIR + ".new")
    with writing(target):
        shutil.rmtree(fresh, ignore_errors=True)
        shutil.copytree(best.run, fresh)
        replace_directory(fresh, target)
    return target


def _status(outcome: TrialOutcome) -> str:
    return f"{FAILED}: {outcome.error}" if outcome.status == FAILED else outcome.status


def _cell(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value).replace("|", "\\|")


def _markdown_table(header: list[str], rows: list[list[str]]) -> str:
    """A markdown table whose columns line up in plain text too."""
    widths = [max(len(line[column]) for line in [header, *rows]) for column in range(len(header))]

    def line(cells: list[str]) -> str:
        return "| " + " | ".join(cell.ljust(width) for cell, width in zip(cells, widths)) + " |"

    return "\n".join([line(header), line(["-" * width for width in widths]), *(line(row) for row in rows)])


def _replace(path: Path, text: str) -> None:
    temporary = path.with_name(path.name + ".tmp")
    with writing(path):
        temporary.write_text(text)
        os.replace(temporary, path)


def _float(text: str | None) -> float:
    try:
        return float(text) if text else math.nan
    except ValueError:
        return math.nan
