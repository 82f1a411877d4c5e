"""The Ray Tune side of `imitation sweep`: the trial (a function trainable that runs the train
command in its worker process and reports each logged row), the searcher and scheduler, one
line per finished trial, and the trials' outcomes once Tune is done.

Imported only inside a Ray session (`imitation.jobs.sweep`): it imports Ray at the top.
"""

from __future__ import annotations

import math
import os
import re
import shutil
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ray import tune
from ray.tune.experiment import Trial
from ray.tune.schedulers import ASHAScheduler, FIFOScheduler
from ray.tune.search.basic_variant import BasicVariantGenerator

from imitation.errors import ImitationError
from imitation.jobs.loop import Learner, Row, observe_rows
from imitation.jobs.sweep_config import Distribution, SweepConfig
from imitation.jobs.sweep_results import (
    FAILED,
    FINISHED,
    RUNS_DIR,
    STOPPED,
    UNFINISHED,
    TrialOutcome,
    finished_run,
    read_rows,
    run_result,
    scoped,
)
from imitation.runs import has_checkpoint

EXPERIMENT = "tune"  # Tune's experiment state, in the sweep's folder
STEPS = "steps_completed"  # the learner's steps so far: ASHA's clock
FINISHED_KEY = "run_finished"  # in a trial's last report: its command ran to its end
UNBOUNDED_STEPS = 2**31  # ASHA needs a longest trial; unset, each trial ends where its command ends it


@dataclass(frozen=True)
class TrialSetup:
    """What every trial needs besides its flags' values: the sweep, where runs go, the command
    line's runner (picklable: Ray ships it to the workers), and the directory the sweep's
    relative paths start from."""

    config: SweepConfig
    runs: Path
    run_train: Callable[[list[str]], None]
    cwd: str


def trial(params: dict[str, Any], setup: TrialSetup) -> None:
    """One trial: the train command with `params`, into `RUNS/<trial id>`; each row with a
    finite metric goes to Tune (ASHA may stop the trial there), and the trial's result in the
    sweep's scope last. A run it finished before (a sweep interrupted before Tune recorded it)
    is reported, not redone; an interrupted one continues from its checkpoint."""
    os.chdir(setup.cwd)  # Tune starts each trial in a folder of its own; the config's paths are the user's
    config = setup.config
    run = setup.runs / tune.get_context().get_trial_id()
    argv = config.argv(params, str(run))
    if not finished_run(run):
        if has_checkpoint(run.with_name(run.name + ".partial")):
            argv.append("--resume")
        try:
            with observe_rows(reporter(config.metric, config.command, tune.report)):
                setup.run_train(argv)
        except TrialStopped:
            sys.exit(0)  # how Tune ends a stopped trial's thread
    value, steps = run_result(run, command=config.command, metric=config.metric, mode=config.mode, scope=config.scope)
    tune.report({config.metric: value, STEPS: steps, FINISHED_KEY: 1})


class TrialStopped(KeyboardInterrupt):
    """Tune stopped the trial (ASHA, or the sweep's Ctrl-C): like a Ctrl-C, it leaves the run's
    last checkpoint in RUN.partial, which a rerun of an interrupted sweep continues from."""


def reporter(metric: str, command: str, report: Callable[[dict[str, float]], None]) -> Callable[[Learner, Row], None]:
    """The row observer of a trial: each row with a finite `metric` goes to `report` (Tune's),
    its finite figures and the learner's steps so far; a row without the column fails the trial
    at its first step rather than after its last."""

    def observe(learner: Learner, row: Row) -> None:
        if metric not in row:
            raise ImitationError(f"{command} logs no column {metric!r}; its rows have {', '.join(row)}")
        if not math.isfinite(row[metric]):
            return
        try:
            report({key: value for key, value in row.items() if math.isfinite(value)} | {STEPS: learner.completed})
        except SystemExit:  # Tune's way of stopping a trial: it raises in the trial's next report
            raise TrialStopped from None

    return observe


class TrialLines(tune.Callback):
    """One line on stderr per trial that ends, terminal or log alike."""

    def __init__(self, metric: str, total: int) -> None:
        self.metric, self.total = metric, total

    def on_trial_complete(self, iteration: int, trials: list[Trial], trial: Trial, **info: Any) -> None:
        result = trial.last_result
        how = "finished" if result.get(FINISHED_KEY) else "stopped early by ASHA"
        value = result.get(self.metric)
        figure = f"{self.metric} {value:.4g}" if isinstance(value, float | int) else f"no {self.metric}"
        self._line(trials, trial, f"{how} after {result.get(STEPS, 0)} steps, {figure}")

    def on_trial_error(self, iteration: int, trials: list[Trial], trial: Trial, **info: Any) -> None:
        self._line(trials, trial, f"failed: {_logged_error(trial)}")

    def _line(self, trials: list[Trial], trial: Trial, what: str) -> None:
        ended = sum(1 for each in trials if each.status in (Trial.TERMINATED, Trial.ERROR) or each is trial)
        params = ", ".join(
            f"{key} {value:.4g}" if isinstance(value, float) else f"{key} {value}" for key, value in trial.config.items()
        )
        print(f"[sweep] trial {ended}/{self.total} {trial.trial_id} ({params}) {what}", file=sys.stderr, flush=True)


def run_trials(config: SweepConfig, out: Path, run_train: Callable[[list[str]], None]) -> list[TrialOutcome]:
    """Run the sweep's trials on the connected Ray, or continue the experiment in `out` where
    one was interrupted (its finished trials are not run again); every trial's outcome."""
    setup = TrialSetup(config=config, runs=out / RUNS_DIR, run_train=run_train, cwd=os.getcwd())
    trainable = tune.with_resources(
        tune.with_parameters(trial, setup=setup), {"cpu": config.cpus_per_trial, "gpu": config.gpus_per_trial}
    )
    experiment = out / EXPERIMENT
    if tune.Tuner.can_restore(experiment):
        # Errored trials run again: a Ctrl-C in a terminal reaches the workers too, which fail.
        tuner = tune.Tuner.restore(str(experiment), trainable, resume_unfinished=True, restart_errored=True)
    else:
        tuner = tune.Tuner(
            trainable,
            param_space={key: _domain(distribution) for key, distribution in config.space.items()},
            tune_config=tune.TuneConfig(
                metric=config.metric,
                mode=config.mode,
                num_samples=config.trials,
                search_alg=_searcher(config),
                scheduler=_scheduler(config),
                reuse_actors=True,  # a worker keeps its imports (torch) from one trial to the next: 2x faster
            ),
            run_config=tune.RunConfig(
                name=EXPERIMENT,
                storage_path=str(out),
                verbose=0,
                callbacks=[TrialLines(config.metric, config.total_trials)],
            ),
        )
    grid = tuner.fit()
    results = [grid[index] for index in range(len(grid))]  # a ResultGrid is indexed; its stubs say nothing of iterating
    outcomes = sorted((_outcome(result, config, setup.runs) for result in results), key=lambda outcome: outcome.trial)
    for outcome in outcomes:
        if outcome.status == STOPPED:  # what a trial stopped in the middle of a step may have left
            shutil.rmtree(setup.runs / f"{outcome.trial}.partial", ignore_errors=True)
    return outcomes


def _domain(distribution: Distribution) -> Any:
    kind, values = distribution.kind, distribution.values
    if kind == "choice":
        return tune.choice(list(values))
    if kind == "grid":
        return tune.grid_search(list(values))
    low, high = values
    if kind == "randint":
        return tune.randint(int(low), int(high) + 1)  # Tune's upper end is excluded, the config's included
    return tune.loguniform(float(low), float(high)) if kind == "loguniform" else tune.uniform(float(low), float(high))


def _searcher(config: SweepConfig) -> Any:
    if config.search == "optuna":
        from ray.tune.search.optuna import OptunaSearch

        return OptunaSearch(seed=config.seed)
    return BasicVariantGenerator(random_state=config.seed)


def _scheduler(config: SweepConfig) -> Any:
    if config.asha is None:
        return FIFOScheduler()
    return ASHAScheduler(
        time_attr=STEPS,
        grace_period=config.asha.grace_period,
        reduction_factor=config.asha.reduction_factor,
        max_t=config.asha.max_steps or UNBOUNDED_STEPS,
    )


def _outcome(result: Any, config: SweepConfig, runs: Path) -> TrialOutcome:
    """A trial's outcome: from its run directory when it finished, else from what Tune recorded."""
    metrics = result.metrics or {}
    outcome = TrialOutcome(trial=str(metrics.get("trial_id")), params=dict(result.config or {}), status=UNFINISHED)
    run = runs / outcome.trial
    if result.error is not None:
        outcome.status, outcome.error = FAILED, _error_line(result.error)
        outcome.run = run if finished_run(run) else None
    elif finished_run(run):
        rows = read_rows(run)
        values = [row.get(config.metric, math.nan) for row in rows]
        outcome.status, outcome.run, outcome.steps = FINISHED, run, len(rows)
        outcome.metric = scoped(values, mode=config.mode, scope=config.scope)
    elif metrics.get("done"):
        frame = result.metrics_dataframe
        values = list(frame[config.metric]) if frame is not None and config.metric in frame else []
        outcome.status, outcome.steps = STOPPED, metrics.get(STEPS)
        outcome.metric = scoped([float(value) for value in values], mode=config.mode, scope=config.scope)
    return outcome


def _logged_error(trial: Trial) -> str:
    """The last line of the error Tune has just logged for `trial`, without the error's class."""
    try:
        text = Path(trial.error_file).read_text() if trial.error_file else ""
    except OSError:
        text = ""
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    return re.sub(r"^[\w.]+: ", "", lines[-1]) if lines else "see the table"


def _error_line(error: BaseException | None) -> str:
    """The one line of a trial's failure: the innermost of Ray's wrapped errors, an ImitationError
    as its message, anything else as the last line of its text."""
    seen = error
    for _ in range(10):  # Ray's wrappers, a few deep
        inner = getattr(seen, "cause", None) or getattr(seen, "__cause__", None)
        if not isinstance(inner, BaseException) or inner is seen:
            break
        seen = inner
    if isinstance(seen, ImitationError):
        return str(seen)
    lines = [line.strip() for line in str(seen).splitlines() if line.strip()]
    return lines[-1] if lines else type(seen).__name__
