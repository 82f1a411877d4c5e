"""The Ray Tune side of `imitation sweep`: the trial (a function trainable that runs the train
command in its worker process and reports each logged row), the searcher and scheduler, and a
callback that prints one line per ended trial and keeps the sweep's record of its trials
(`imitation.jobs.sweep_trials`) up to date.

Tune's own experiment state goes to a temporary folder, removed when Tune is done, and is never
restored from (Tune's restore unpickles it): a rerun continues from the sweep's JSON record.

Imported only inside a Ray session (`imitation.jobs.sweep`): it imports Ray at the top.
"""

from __future__ import annotations

import math
import os
import re
import sys
import tempfile
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
from imitation.jobs.sweep_results import FAILED, FINISHED, RUNS_DIR, STOPPED, UNFINISHED, finished_run, run_result, scoped
from imitation.jobs.sweep_trials import SweepTrials
from imitation.runs import has_checkpoint
from imitation.seeding import SEED_BOUND

STEPS = "steps_completed"  # the learner's steps so far: ASHA's clock
FINISHED_KEY = "run_finished"  # in a trial's last report: its command ran to its end
PLANNED = "planned_trial"  # the one parameter of a trial the sweep named: its name
UNBOUNDED_STEPS = 2**31  # ASHA needs a longest trial; unset, each trial ends where its command ends it
ERROR_CHARACTERS = 200  # a failed trial's line and table cell: Ray's messages run to pages
# Ray's account of a trial whose process died, and what it means for the trial.
RAY_DEATHS = {
    "because its worker process has died": "its Ray worker process died (killed, or out of memory)",
    "because its owner has died": "Ray stopped while it ran",
}


@dataclass(frozen=True)
class TrialSetup:
    """What every trial needs besides its flags' values: the sweep, where runs go, the values of
    the trials the sweep named, the command line's runner (picklable: Ray ships it to the
    workers), and the directory the sweep's relative paths start from."""

    config: SweepConfig
    runs: Path
    planned: dict[str, dict[str, Any]]
    run_train: Callable[[list[str]], None]
    cwd: str


def trial(params: dict[str, Any], setup: TrialSetup) -> None:
    """One trial: the train command with its flags' values, into `RUNS/<trial name>`; each row
    with a finite metric goes to Tune (ASHA may stop the trial there), and the trial's result in
    the sweep's scope last. A run it finished before (a sweep interrupted before it was recorded)
    is reported, not redone; an interrupted one continues from its checkpoint."""
    os.chdir(setup.cwd)  # Tune starts each trial in a folder of its own; the config's paths are the user's
    config = setup.config
    name = params.get(PLANNED) or tune.get_context().get_trial_id()
    run = setup.runs / name
    argv = config.argv(setup.planned.get(name, params), str(run))
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


class TrialRecorder(tune.Callback):
    """Keeps the sweep's record of each trial as Tune runs it (started, its figures, how it
    ended), and prints one line on stderr per trial that ends, terminal or log alike."""

    def __init__(self, config: SweepConfig, trials: SweepTrials, lines: int) -> None:
        self.config, self.trials, self.lines = config, trials, lines  # a descriptor: Tune pickles its callbacks

    def on_trial_start(self, iteration: int, trials: list[Trial], trial: Trial, **info: Any) -> None:
        self.trials.started(_name(trial), _params(trial, self.trials))

    def on_trial_result(self, iteration: int, trials: list[Trial], trial: Trial, result: dict, **info: Any) -> None:
        record = self.trials.records[_name(trial)]
        value = result.get(self.config.metric)
        if isinstance(value, float | int) and math.isfinite(value):
            seen = [] if record.metric is None else [record.metric]
            record.metric = scoped([*seen, float(value)], mode=self.config.mode, scope=self.config.scope)
        record.steps = result.get(STEPS, record.steps)
        self.trials.save()

    def on_trial_complete(self, iteration: int, trials: list[Trial], trial: Trial, **info: Any) -> None:
        result = trial.last_result
        if not (result.get(FINISHED_KEY) or result.get("done")):
            return  # Tune was stopped (Ctrl-C) while the trial ran: it stays unfinished, to run again
        record = self.trials.records[_name(trial)]
        record.status = FINISHED if result.get(FINISHED_KEY) else STOPPED
        if result.get(FINISHED_KEY):
            record.metric = result.get(self.config.metric)
        self.trials.save()
        how = "finished" if record.status == FINISHED else "stopped early by ASHA"
        figure = f"{self.config.metric} {record.metric:.4g}" if record.metric is not None else f"no {self.config.metric}"
        self._line(trial, f"{how} after {record.steps or 0} steps, {figure}")

    def on_trial_error(self, iteration: int, trials: list[Trial], trial: Trial, **info: Any) -> None:
        record = self.trials.records[_name(trial)]
        record.status, record.error = FAILED, _logged_error(trial)
        self.trials.save()
        self._line(trial, f"failed: {record.error}")

    def _line(self, trial: Trial, what: str) -> None:
        ended = sum(record.status != UNFINISHED for record in self.trials.records.values())
        params = ", ".join(
            f"{key} {value:.4g}" if isinstance(value, float) else f"{key} {value}"
            for key, value in _params(trial, self.trials).items()
        )
        total = self.config.total_trials
        os.write(self.lines, f"[sweep] trial {ended}/{total} {_name(trial)} ({params}) {what}\n".encode())


def _name(trial: Trial) -> str:
    return str(trial.config.get(PLANNED) or trial.trial_id)


def _params(trial: Trial, trials: SweepTrials) -> dict[str, Any]:
    planned = trial.config.get(PLANNED)
    return dict(trials.records[planned].params) if planned else dict(trial.config)


def run_trials(
    config: SweepConfig, out: Path, run_train: Callable[[list[str]], None], trials: SweepTrials, lines: int
) -> None:
    """Run every trial of `trials` that has not ended (random search's are all planned), then,
    for Optuna, sample the trials the sweep has not yet started, on the connected Ray; a line to
    file descriptor `lines` per trial that ends. Returns when every trial has ended, or when Ctrl-C stopped Tune
    (the unended ones stay so)."""
    setup = TrialSetup(
        config=config,
        runs=out / RUNS_DIR,
        planned={name: record.params for name, record in trials.records.items()},
        run_train=run_train,
        cwd=os.getcwd(),
    )
    again = trials.unended()
    if again:
        _fit(setup, trials, lines, {PLANNED: tune.grid_search(again)}, BasicVariantGenerator(), samples=1)
        if trials.unended():
            return
    new = config.total_trials - len(trials.records)
    if new > 0:
        space = {key: _domain(distribution) for key, distribution in config.space.items()}
        _fit(setup, trials, lines, space, _searcher(config, trials), samples=new)


def _fit(setup: TrialSetup, trials: SweepTrials, lines: int, space: dict[str, Any], searcher: Any, *, samples: int) -> None:
    config = setup.config
    trainable = tune.with_resources(
        tune.with_parameters(trial, setup=setup), {"cpu": config.cpus_per_trial, "gpu": config.gpus_per_trial}
    )
    with tempfile.TemporaryDirectory(prefix="imitation-sweep-tune-") as storage:
        tuner = tune.Tuner(
            trainable,
            param_space=space,
            tune_config=tune.TuneConfig(
                metric=config.metric,
                mode=config.mode,
                num_samples=samples,
                search_alg=searcher,
                scheduler=_scheduler(config),
                reuse_actors=True,  # a worker keeps its imports (torch) from one trial to the next: 2x faster
            ),
            run_config=tune.RunConfig(
                name="tune", storage_path=storage, verbose=0, callbacks=[TrialRecorder(config, trials, lines)]
            ),
        )
        tuner.fit()


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


def _searcher(config: SweepConfig, trials: SweepTrials) -> Any:
    """Optuna, told the results of the trials that ended before it samples the rest. Its
    first samples are random draws: a rerun seeds them past those of the trials already
    recorded, which the sweep's own seed would draw again."""
    import optuna
    from ray.tune.search.optuna import OptunaSearch

    optuna.logging.set_verbosity(optuna.logging.WARNING)  # its study notice would sit among the trials' lines
    told = [record for record in trials.ended() if record.metric is not None]
    return OptunaSearch(
        seed=(config.seed + len(trials.records)) % SEED_BOUND,
        points_to_evaluate=[record.params for record in told] or None,
        evaluated_rewards=[record.metric for record in told] or None,
    )


def _scheduler(config: SweepConfig) -> Any:
    if config.asha is None:
        return FIFOScheduler()
    return ASHAScheduler(
        time_attr=STEPS,
        grace_period=config.asha.grace_period,
        reduction_factor=config.asha.reduction_factor,
        max_t=config.asha.max_steps or UNBOUNDED_STEPS,
    )


def _logged_error(trial: Trial) -> str:
    """The error Tune has just logged for `trial` as one line: what became of its process when
    Ray says it died (a page of ids and causes), else the error's last line without its class."""
    try:
        text = Path(trial.error_file).read_text() if trial.error_file else ""
    except OSError:
        text = ""
    for cause, line in RAY_DEATHS.items():
        if cause in text:
            return line
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    line = re.sub(r"^[\w.]+: ", "", lines[-1]) if lines else "no error was logged"
    return line if len(line) <= ERROR_CHARACTERS else line[: ERROR_CHARACTERS - 1] + "…"
