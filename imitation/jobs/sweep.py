"""`imitation sweep CONFIG.yaml`: a hyperparameter search over a `train` command's flags with
Ray Tune (random search or Optuna, ASHA early stopping), into one folder:

    OUT/
      sweep.json      the sweep's settings: a rerun with other settings is refused
      trials.json     each trial's flags' values, how it ended and its figures (what a rerun continues from)
      ray.log         what Ray and Tune printed (imitation.jobs.sweep_process)
      runs/TRIAL/     each trial's run directory, as `train` writes it
      results.csv     one row per trial: its flags, its metric, steps run, how it ended, its run
      results.md      the same, aligned, with the best trial marked
      best/           a copy of the best finished trial's run directory

Rerunning the same command after Ctrl-C continues the experiment: finished trials are kept,
unfinished and failed ones run again under their names and with their values (from their run's
checkpoint where they saved one). Continuing reads only the sweep's JSON and the runs' checkpoints
(imitation.jobs.sweep_trials), never Ray Tune's pickled state.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from imitation.errors import ImitationError
from imitation.jobs.sweep_config import SweepConfig
from imitation.jobs.sweep_process import INTERRUPTED, run_apart
from imitation.jobs.sweep_results import (
    FAILED,
    FINISHED,
    RUNS_DIR,
    STOPPED,
    TrialOutcome,
    choose_best,
    copy_best,
    finished_run,
    read_rows,
    scoped,
    write_results,
)
from imitation.jobs.sweep_trials import SweepTrials
from imitation.output import OutputLock, check_target, os_error
from imitation.ray_engine import INSTALL_HINT, LOCAL
from imitation.runs import write_json

SETTINGS_FILE = "sweep.json"


def sweep_job(
    config: SweepConfig,
    out: str | os.PathLike,
    run_train: Callable[[list[str]], None],
    *,
    ray_address: str = LOCAL,
    cpus: int | None = None,
) -> dict[str, Any]:
    """Run (or continue) the sweep `config` into `out`: each trial runs `run_train(argv)`, a
    `train` command line, in a Ray worker. Returns the summary; raises KeyboardInterrupt, after
    writing the table of what ran, when Ctrl-C stopped it before every trial ended."""
    _require_tune()
    out = Path(out).absolute()
    check_target(out, directory=True)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise os_error(out, error, "cannot create") from None
    started = time.monotonic()
    with OutputLock(out):
        resumed = _claim(out, config)
        trials = SweepTrials.open(out, config, resumed=resumed)
        stopped = None
        if trials.unended() or len(trials.records) < config.total_trials:
            stopped = run_apart(config, out, run_train, ray_address=ray_address, cpus=cpus)
            trials = SweepTrials.open(out, config, resumed=True)  # as Tune's process left it
        outcomes = _outcomes(trials, config, out / RUNS_DIR)
        best = choose_best(outcomes, mode=config.mode)
        counts = {status: sum(outcome.status == status for outcome in outcomes) for status in (FINISHED, STOPPED, FAILED)}
        missing = config.total_trials - counts[FINISHED] - counts[STOPPED] - counts[FAILED]
        table = write_results(out, outcomes, metric=config.metric, heading=_heading(config, outcomes, best, missing))
        if best is not None:
            copy_best(out, best)
    if stopped not in (None, INTERRUPTED):
        raise ImitationError(
            f"{stopped}; {config.total_trials - missing} of {config.total_trials} trials ended (table: {out / 'results.md'}); "
            "run the same command again to continue the sweep"
        )
    if missing > 0:
        raise KeyboardInterrupt(
            f"the sweep stopped with {config.total_trials - missing} of {config.total_trials} trials ended (table: "
            f"{out / 'results.md'}); run the same command again to continue it"
        )
    if counts[FAILED] and not counts[FINISHED] and not counts[STOPPED]:
        first = next(outcome for outcome in outcomes if outcome.status == FAILED)
        raise ImitationError(
            f"every trial of the sweep failed, the first ({first.trial}) with: {first.error} (table: {out / 'results.md'})"
        )
    return {
        "out": str(out),
        "resumed": resumed,
        "trials": len(outcomes),
        "finished": counts[FINISHED],
        "stopped_early": counts[STOPPED],
        "failed": counts[FAILED],
        "metric": config.metric,
        "mode": config.mode,
        "best": None
        if best is None
        else {"trial": best.trial, "params": best.params, config.metric: best.metric, "run": str(out / "best")},
        "table": table,
        "seconds": time.monotonic() - started,
    }


def _outcomes(trials: SweepTrials, config: SweepConfig, runs: Path) -> list[TrialOutcome]:
    """Every trial as the table shows it: from its run directory when it finished (also one
    that finished just before Tune could record it), else from the sweep's record. A trial
    stopped early leaves no run: what it may have left in the middle of a step is removed."""
    outcomes = []
    for record in sorted(trials.records.values(), key=lambda record: record.trial):
        outcome = TrialOutcome(**{**vars(record), "run": None, "best": False})
        run = runs / record.trial
        if finished_run(run):
            rows = read_rows(run)
            values = [row.get(config.metric, math.nan) for row in rows]
            outcome.status, outcome.run, outcome.steps, outcome.error = FINISHED, run, len(rows), ""
            outcome.metric = scoped(values, mode=config.mode, scope=config.scope)
        elif record.status == STOPPED:
            shutil.rmtree(runs / f"{record.trial}.partial", ignore_errors=True)
        outcomes.append(outcome)
    return outcomes


def _require_tune() -> None:
    """Ray Tune, or a one-line error saying how to install it (Ray without its tune extra fails too)."""
    try:
        import ray.tune  # noqa: F401
    except ImportError:
        raise ImitationError(f"imitation sweep needs Ray Tune, which is not installed: {INSTALL_HINT}") from None


def _claim(out: Path, config: SweepConfig) -> bool:
    """Make `out` this sweep's folder: a new or empty one, or one of the same sweep to continue
    (whether it was one)."""
    settings = json.loads(json.dumps(config.to_json()))
    record = out / SETTINGS_FILE
    if record.is_file():
        try:
            saved = json.loads(record.read_text())
        except (OSError, ValueError) as error:
            raise ImitationError(f"{record}: unreadable ({error})") from None
        if saved != settings:
            key = next(key for key in settings if not isinstance(saved, dict) or saved.get(key) != settings[key])
            raise ImitationError(
                f"{out}: holds a sweep with other settings ({key} differs from {config.path}'s); "
                "continue it with the config it was started with, or give another --out"
            )
        return True
    if out.is_dir() and any(out.iterdir()):
        raise ImitationError(f"{out}: not empty and not a sweep's folder (no {SETTINGS_FILE}); give a new or empty --out")
    try:
        out.mkdir(exist_ok=True)
        write_json(record, settings)
    except OSError as error:
        raise os_error(out, error, "cannot create") from None
    return False


def _heading(config: SweepConfig, outcomes: list[Any], best: Any, missing: int) -> str:
    scope = "best" if config.scope == "best" else "last"
    lines = [
        f"# Sweep: {config.command} ({config.path.name})",
        "",
        f"{len(outcomes)} trials, {config.search} search, "
        f"{'ASHA' if config.asha is not None else 'no early stopping'}; metric {config.metric} "
        f"({'lower' if config.mode == 'min' else 'higher'} is better; each trial's {scope} value).",
    ]
    if best is not None:
        lines.append(f"Best: {best.trial}, {config.metric} {best.metric:.4g}; its run directory is copied to best/.")
    if missing > 0:
        lines.append(
            f"Interrupted: {missing} of {config.total_trials} trials have not ended; run the same command again to continue."
        )
    return "\n".join(lines)
