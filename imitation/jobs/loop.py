"""The one training loop: every learner is a state object plus a step, and this loop runs it.

A learner (`Learner`) knows its equations and nothing of run directories, Ctrl-C or save
intervals. `run` steps it until it is done and owns everything around the steps:

- resuming: a checkpoint given in `Checkpointing.resume` is loaded into the learner first;
- saving: every `Checkpointing.interval` steps (a tenth of the run by default) the learner's
  `state_dict()` is handed to `Checkpointing.save` (the run directory writes it), and after the
  last step, so that a Ctrl-C in the job's work after training (a final evaluation) loses nothing;
- Ctrl-C (and SIGTERM, which the CLI routes to the same handler) is deferred to the end of the
  current step, where a checkpoint is saved and `TrainingInterrupted` raised; a second Ctrl-C
  stops at once. A learner whose steps are long (`Interruptible`: BC, whose step is an epoch)
  is told of the request and stops at the next boundary within its step (a minibatch), and the
  checkpoint then holds its place there;
- logging and progress: each step's row goes to `log` and to a progress bar on a terminal, or,
  when stderr is a log, to a line when training starts and every 30 seconds, steps ending or not,
  saying where within its step the learner is when it has a `within()` (`progress_bar`'s heartbeat);
- observing: within `observe_rows(callback)`, each row also goes to `callback(learner, row)`, so
  that a caller several jobs above the loop (a sweep's trial) sees the rows without every job
  passing a callback down.

A checkpoint is a pair (tensors, state): tensors go to a safetensors file, everything else to
JSON (`imitation.checkpoints` has the helpers learners build theirs with); nothing is pickled.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

from imitation.checkpoints import CheckpointData, Tensors, snapshot
from imitation.progress import progress_bar

Row = dict[str, float]


class TrainingInterrupted(KeyboardInterrupt):
    """Ctrl-C stopped training after a checkpoint was saved; the message says where."""


class Learner(Protocol):
    """What `run` needs of an algorithm: its state (`state_dict`/`load_state_dict`) and one step
    of it (an update, epoch, round or iteration) that returns the row to log."""

    name: str  # for messages: "PPO", "BC", "DAgger", "mce IRL"
    unit: str  # what one step is: "update", "epoch", "round", "iteration"
    total: int  # the steps planned

    @property
    def completed(self) -> int: ...  # the steps taken, counting those before a checkpoint

    @property
    def done(self) -> bool: ...  # all steps taken, or stopped early (converged, no progress)

    def position(self) -> str: ...  # where it stands, for the message of an interruption

    def progress(self, row: Row) -> dict[str, str]: ...  # the row's figures a progress bar shows

    def step(self) -> Row | None: ...  # None only for an `Interruptible` learner stopped within its step

    def state_dict(self) -> CheckpointData: ...

    def load_state_dict(self, checkpoint: CheckpointData) -> None: ...


@runtime_checkable
class Interruptible(Protocol):
    """A learner whose step is long and can stop midway at a boundary of its own (BC: between
    minibatches). `run` hands it `requested` (whether Ctrl-C asked to stop) with `stop_when`; a
    step that stops returns None instead of its row, `position()` then says where within the
    step it is, and `state_dict()` holds that place, so that a resumed run goes on from it as if
    never stopped. `within()` says where within the current step it is, for progress lines."""

    def stop_when(self, requested: Callable[[], bool]) -> None: ...

    def within(self) -> str: ...


@dataclass
class Checkpointing:
    """`save(tensors, state)` every `every` steps (None: every tenth of the run), after the last
    step and when interrupted; `at_start(tensors, state)`, when given, before the first step of a
    run not resumed (for a learner whose step can be stopped midway: a second Ctrl-C, SIGKILL),
    a checkpoint that holds no work done; `resume`, when given, is
    the checkpoint to continue from. `agree(requested)`, for the processes of a data-parallel run,
    says whether any of them was asked to stop, so that all stop after the same step."""

    save: Callable[[Tensors, dict[str, Any]], None]
    every: int | None = None
    at_start: Callable[[Tensors, dict[str, Any]], None] | None = None
    resume: CheckpointData | None = None
    agree: Callable[[bool], bool] | None = None

    def interval(self, total: int) -> int:
        return self.every if self.every is not None else max(1, total // 10)


class StopAtBoundary:
    """Within the block, Ctrl-C only sets `requested`; the loop checks it between steps. The
    first Ctrl-C restores the previous handler, so a second one interrupts immediately. Outside
    the main thread (where signal handlers cannot be set) it does nothing."""

    def __init__(self, *, enabled: bool = True) -> None:
        self.requested = False
        self._enabled = enabled
        self._previous: Any = None
        self._active = False

    def _handle(self, signum: int, frame: Any) -> None:
        self.requested = True
        signal.signal(signal.SIGINT, self._previous)

    def __enter__(self) -> StopAtBoundary:
        if self._enabled and threading.current_thread() is threading.main_thread():
            self._previous = signal.signal(signal.SIGINT, self._handle)
            self._active = True
        return self

    def __exit__(self, *exc: Any) -> None:
        if self._active:
            signal.signal(signal.SIGINT, self._previous)


RowObserver = Callable[["Learner", Row], None]
_observer: ContextVar[RowObserver | None] = ContextVar("row_observer", default=None)


@contextmanager
def observe_rows(callback: RowObserver) -> Iterator[None]:
    """Within the block (in this thread or task), every row a `run` logs also goes to
    `callback(learner, row)`, after `log` has it. Only the outermost `run` is observed: a learner
    run inside another's step is part of that step."""
    token = _observer.set(callback)
    try:
        yield
    finally:
        _observer.reset(token)


@contextmanager
def _outermost() -> Iterator[RowObserver | None]:
    """The observer of this `run`, hidden from the runs inside it for the block."""
    observer = _observer.get()
    token = _observer.set(None)
    try:
        yield observer
    finally:
        _observer.reset(token)


def run(
    learner: Learner,
    *,
    checkpoints: Checkpointing | None = None,
    log: Callable[[Row], None] | None = None,
    progress: bool = False,
) -> list[Row]:
    """Step `learner` until it is done; the rows logged by this call. With `checkpoints`, resume
    from `checkpoints.resume`, save every interval, and stop on Ctrl-C with a checkpoint saved
    (`TrainingInterrupted`); a run that finishes is not interrupted."""
    if checkpoints is not None and checkpoints.resume is not None:
        learner.load_state_dict(checkpoints.resume)
    rows: list[Row] = []
    bar = progress_bar(
        total=learner.total,
        initial=learner.completed,
        desc=learner.name,
        unit=learner.unit,
        enabled=progress,
        detail=learner.within if isinstance(learner, Interruptible) else None,
    )
    # Within a step only where one process decides alone: the processes of a data-parallel run
    # agree on stopping between steps.
    interruptible = isinstance(learner, Interruptible) and checkpoints is not None and checkpoints.agree is None
    stop_when = learner.stop_when if isinstance(learner, Interruptible) and interruptible else None
    with bar, StopAtBoundary(enabled=checkpoints is not None) as stop, _outermost() as observer:
        if stop_when is not None:
            stop_when(lambda: stop.requested)
        try:
            _steps(learner, checkpoints, log, bar, stop, observer, rows)
        finally:
            if stop_when is not None:
                stop_when(lambda: False)
    return rows


def _steps(
    learner: Learner,
    checkpoints: Checkpointing | None,
    log: Callable[[Row], None] | None,
    bar: Any,
    stop: StopAtBoundary,
    observer: RowObserver | None,
    rows: list[Row],
) -> None:
    """`run`'s loop: each step's row logged, observed and shown, checkpoints saved, Ctrl-C honoured."""
    if checkpoints is not None and checkpoints.at_start is not None and checkpoints.resume is None:
        checkpoints.at_start(*snapshot(*learner.state_dict()))
    while not learner.done:
        row = learner.step()
        if row is None:  # an Interruptible learner stopped within its step, at the request
            assert checkpoints is not None  # it is asked to stop only then
            checkpoints.save(*snapshot(*learner.state_dict()))
            raise TrainingInterrupted(f"{learner.name} stopped after {learner.position()}")
        rows.append(row)
        if log is not None:
            log(row)
        if observer is not None:
            observer(learner, row)
        bar.set_postfix(learner.progress(row), refresh=False)
        bar.update()
        if checkpoints is None:
            continue
        if learner.done:  # the trained state, so that a Ctrl-C in what follows (an evaluation) loses nothing
            checkpoints.save(*snapshot(*learner.state_dict()))
            continue
        interrupted = stop.requested if checkpoints.agree is None else checkpoints.agree(stop.requested)
        if interrupted or learner.completed % checkpoints.interval(learner.total) == 0:
            checkpoints.save(*snapshot(*learner.state_dict()))
        if interrupted:
            raise TrainingInterrupted(f"{learner.name} stopped after {learner.position()}")
