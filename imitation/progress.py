"""Progress that reaches the user whether stderr is a terminal or a log file.

tqdm draws its bar only on a terminal (`disable=None`), so a job whose output goes to a file or
a pipe (a batch script, CI, `nohup`) used to say nothing for minutes. `progress_bar` gives tqdm's
bar on a terminal and otherwise `ProgressLines`: a plain line every 30 seconds and one at the end,
with the position, the latest figures, the time spent and an estimate of the time left. With
`heartbeat`, a line also 3 seconds after it starts and every 30 seconds while no step ends (a step
that takes minutes: an epoch of BC on camera frames), saying where within the step the work is
(`detail`). The first waits those 3 seconds so that work refused at once (a setting checked after
the demos load) still answers with its one line alone.

`activity` does the same for long work that is not a loop of steps (loading demos): a line 3
seconds after it starts and one every 30 seconds until it ends, on a terminal as on a log.
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from typing import Any, TextIO

from tqdm import tqdm

FIRST_LINE_SECONDS = 3.0


class _Ticker:
    """Calls `tick()` from a thread of its own `first` seconds after it starts and whenever nine
    tenths of `every` seconds pass without `touch()`, until `stop()`: the margin keeps lines
    within `every` of each other on a busy machine, whose scheduler may wake the thread late."""

    def __init__(self, tick: Callable[[], None], every: float, first: float) -> None:
        self._tick, self.every = tick, 0.9 * every
        self._last = time.monotonic() - self.every + first
        self._stopped = threading.Event()
        self._thread = threading.Thread(target=self._run, name="progress-heartbeat", daemon=True)
        self._thread.start()

    def touch(self) -> None:
        self._last = time.monotonic()

    def _run(self) -> None:
        while not self._stopped.wait(max(0.0, self._last + self.every - time.monotonic())):
            if time.monotonic() - self._last >= self.every:
                self._last = time.monotonic()
                self._tick()

    def stop(self) -> None:
        self._stopped.set()
        if self._thread is not threading.current_thread():
            self._thread.join()


class ProgressLines:
    """Progress for a log rather than a terminal: a plain line every `every` seconds and one at
    the end. It has the part of tqdm's interface the toolkit uses (update, set_postfix, close, a
    context manager). With `heartbeat`, a line `first` seconds after it starts and one whenever
    `every` seconds pass without one, steps ending or not, with `detail()` (where within the step
    the work is) beside the position."""

    def __init__(
        self,
        *,
        total: int,
        initial: int = 0,
        desc: str,
        unit: str,
        every: float = 30.0,
        stream: TextIO | None = None,
        heartbeat: bool = False,
        detail: Callable[[], str] | None = None,
        first: float = FIRST_LINE_SECONDS,
    ) -> None:
        self.total, self.count, self.desc, self.unit, self.every = total, initial, desc, unit, every
        self.stream = stream if stream is not None else sys.stderr
        self.started = self.last = time.monotonic()
        self.first = self.shown = initial
        self.postfix = ""
        self.detail = detail
        self._lock = threading.Lock()  # the heartbeat's lines and the steps' do not interleave
        self._ticker: _Ticker | None = None
        if heartbeat:
            self._ticker = _Ticker(lambda: self._line(time.monotonic(), beat=True), every, first)

    def set_postfix(self, values: dict[str, str], refresh: bool = True) -> None:
        self.postfix = ", ".join(f"{key} {value}" for key, value in values.items())

    def update(self, n: int = 1) -> None:
        self.count += n
        now = time.monotonic()
        if now - self.last >= self.every or self.count >= self.total:
            self.last = now
            self._line(now)

    def _line(self, now: float, *, final: bool = False, beat: bool = False) -> None:
        with self._lock:
            if self._ticker is not None:
                self._ticker.touch()
            self.shown = self.count
            spent = now - self.started
            done = self.count - self.first
            left = spent / done * (self.total - self.count) if done else float("nan")
            eta = f", about {_duration(left)} left" if self.count < self.total and left == left and not final else ""
            within = self.detail() if beat and self.detail is not None else ""
            where = f", {within}" if within else ""
            figures = f": {self.postfix}" if self.postfix else ""
            print(
                f"[{self.desc}] {self.unit} {self.count}/{self.total}{where}{figures} ({_duration(spent)} so far{eta})",
                file=self.stream,
                flush=True,
            )

    def close(self) -> None:
        """The last line, when the work ended before its total (an early stop) or between lines."""
        if self._ticker is not None:
            self._ticker.stop()
            self._ticker = None
        if self.count != self.shown:
            self._line(time.monotonic(), final=True)

    def __enter__(self) -> ProgressLines:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def _duration(seconds: float) -> str:
    return f"{seconds:.0f} s" if seconds < 120 else f"{seconds / 60:.1f} min"


def progress_bar(
    *,
    total: int,
    initial: int = 0,
    desc: str,
    unit: str,
    enabled: bool = True,
    heartbeat: bool = False,
    detail: Callable[[], str] | None = None,
) -> Any:
    """A tqdm bar on a terminal; on anything else (a log file, a pipe) `ProgressLines` (with its
    `heartbeat` and `detail`); nothing when not `enabled`."""
    if enabled and not sys.stderr.isatty():
        return ProgressLines(total=total, initial=initial, desc=desc, unit=unit, heartbeat=heartbeat, detail=detail)
    return tqdm(total=total, initial=initial, desc=desc, unit=unit, disable=not enabled, dynamic_ncols=True)


class Activity:
    """Long work that is not a loop of steps, as `activity` reports it: `status` is what the
    lines say of how far it has come (the work sets it as it goes)."""

    def __init__(self, desc: str, what: str, *, every: float, first: float, stream: TextIO) -> None:
        self.desc, self.what, self.stream = desc, what, stream
        self.status = ""
        self.done = 0
        self.started = time.monotonic()
        self._lock = threading.Lock()
        self._ticker = _Ticker(self._line, every, first)

    def count(self, n: int, total: int, unit: str) -> None:
        """`n` more of `total` `unit` done (callable from any thread): the status says how many."""
        with self._lock:
            self.done += n
            self.status = f"{self.done} of {total} {unit}"

    def _line(self) -> None:
        with self._lock:
            spent = time.monotonic() - self.started
            status = f": {self.status}" if self.status else ""
            print(f"[{self.desc}] {self.what}{status} ({_duration(spent)} so far)", file=self.stream, flush=True)

    def close(self) -> None:
        self._ticker.stop()


@contextmanager
def activity(
    desc: str,
    what: str,
    *,
    enabled: bool = True,
    every: float = 30.0,
    first: float = FIRST_LINE_SECONDS,
    stream: TextIO | None = None,
) -> Iterator[Activity | None]:
    """A line "[desc] what" `first` seconds after the block starts and one every `every` seconds
    until it ends (with the `Activity.status` the block sets), on stderr, terminal or not; None
    and silence when not `enabled`."""
    if not enabled:
        yield None
        return
    work = Activity(desc, what, every=every, first=first, stream=stream if stream is not None else sys.stderr)
    try:
        yield work
    finally:
        work.close()


def progress_iter[T](iterable: Iterable[T], *, total: int, desc: str, unit: str, enabled: bool = True) -> Iterator[T]:
    """`iterable`, with progress shown as `progress_bar` shows it."""
    with progress_bar(total=total, desc=desc, unit=unit, enabled=enabled) as bar:
        for item in iterable:
            yield item
            bar.update()
