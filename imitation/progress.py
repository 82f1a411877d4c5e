"""Progress that reaches the user whether stderr is a terminal or a log file.

tqdm draws its bar only on a terminal (`disable=None`), so a job whose output goes to a file or
a pipe (a batch script, CI, `nohup`) would say nothing for minutes. `progress_bar` gives tqdm's
bar on a terminal and otherwise `ProgressLines`: a plain line every 30 seconds and one at the end,
with the position, the latest figures, the time spent and an estimate of the time left, and (its
`heartbeat`) lines also while no step ends (a step that takes minutes: an epoch of BC on camera
frames, an episode recorded at 480×640), saying where within the step the work is (`detail`). `activity` does the same for long
work that is not a loop of steps (loading demos), on a terminal as on a log.

Heartbeat lines keep one clock for the whole process: the first is due 3 seconds after the
process started, each next one 27 seconds after the last progress line (a margin under 30 for a
busy machine's late wake-ups), whichever part of the work is running then. None comes within a
second of a part's start, so that work refused at once (a setting checked after the demos load)
still answers with its one error line alone.
"""

from __future__ import annotations

import os
import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from typing import Any, TextIO

from tqdm import tqdm

FIRST_LINE_SECONDS = 3.0  # after the process started
GRACE_SECONDS = 1.0  # after a part of the work started


def _process_start() -> float:
    """When this process started, on `time.monotonic`'s clock (Linux: its start time in
    /proc/self/stat against the uptime); elsewhere, now."""
    try:
        with open("/proc/self/stat") as stat, open("/proc/uptime") as uptime:
            ticks = int(stat.read().rsplit(")", 1)[1].split()[19])
            age = float(uptime.read().split()[0]) - ticks / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return time.monotonic()
    return time.monotonic() - max(0.0, age)


class _LineClock:
    """When this process's last progress line was printed (None: none yet)."""

    started = _process_start()
    last: float | None = None

    @classmethod
    def printed(cls) -> None:
        cls.last = time.monotonic()

    @classmethod
    def due(cls, every: float) -> float:
        return cls.started + FIRST_LINE_SECONDS if cls.last is None else cls.last + 0.9 * every


class _Ticker:
    """Calls `tick()` (which prints a line) from a thread of its own whenever a heartbeat line is
    due (`_LineClock`, lines `every` seconds apart), but not within `grace` seconds of its start,
    until `stop()`."""

    def __init__(self, tick: Callable[[], None], every: float, grace: float) -> None:
        self._tick, self.every = tick, every
        self._earliest = time.monotonic() + grace
        self._stopped = threading.Event()
        self._thread = threading.Thread(target=self._run, name="progress-heartbeat", daemon=True)
        self._thread.start()

    def _next(self) -> float:
        return max(_LineClock.due(self.every), self._earliest)

    def _run(self) -> None:
        while not self._stopped.wait(max(0.0, self._next() - time.monotonic())):
            if time.monotonic() >= self._next():
                self._tick()

    def stop(self) -> None:
        self._stopped.set()
        if self._thread is not threading.current_thread():
            self._thread.join()


class ProgressLines:
    """Progress for a log rather than a terminal: a plain line every `every` seconds and one at
    the end (not with `last_line` False: work that ends within its first interval and heartbeat
    then prints nothing, so that input refused after it still answers in one line). It has the
    part of tqdm's interface the toolkit uses (update, set_postfix, close, a context manager). With
    `heartbeat`, lines also between steps (the module docstring: none within `grace` seconds of
    its start), with `detail()` (where within the step the work is) beside the position."""

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
        grace: float = GRACE_SECONDS,
        last_line: bool = True,
    ) -> None:
        self.total, self.count, self.desc, self.unit, self.every = total, initial, desc, unit, every
        self.last_line = last_line
        self.stream = stream if stream is not None else sys.stderr
        self.started = self.last = time.monotonic()
        self.first = self.shown = initial
        self.postfix = ""
        self.detail = detail
        self._lock = threading.Lock()  # the heartbeat's lines and the steps' do not interleave
        self._ticker: _Ticker | None = None
        if heartbeat:
            self._ticker = _Ticker(lambda: self._line(time.monotonic(), beat=True), every, grace)

    def set_postfix(self, values: dict[str, str], refresh: bool = True) -> None:
        self.postfix = ", ".join(f"{key} {value}" for key, value in values.items())

    def update(self, n: int = 1) -> None:
        self.count += n
        now = time.monotonic()
        if now - self.last >= self.every or (self.count >= self.total and self.last_line):
            self.last = now
            self._line(now)

    def _line(self, now: float, *, final: bool = False, beat: bool = False) -> None:
        with self._lock:
            _LineClock.printed()
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
        if self.count != self.shown and self.last_line:
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
    heartbeat: bool = True,
    detail: Callable[[], str] | None = None,
    last_line: bool = True,
) -> Any:
    """A tqdm bar on a terminal; on anything else (a log file, a pipe) `ProgressLines` (with its
    `heartbeat`, `detail` and `last_line`); nothing when not `enabled`."""
    if enabled and not sys.stderr.isatty():
        return ProgressLines(
            total=total, initial=initial, desc=desc, unit=unit, heartbeat=heartbeat, detail=detail, last_line=last_line
        )
    return tqdm(total=total, initial=initial, desc=desc, unit=unit, disable=not enabled, dynamic_ncols=True)


def progress_over(items: Iterable[Any], *, total: int, desc: str, unit: str, enabled: bool = True) -> Iterator[Any]:
    """`items`, one by one, counted by `progress_bar` (a bar on a terminal; on a log, lines with a
    heartbeat while the work is long, and none for work done within a second, whose last line
    would stand before a one-line error of what follows); the bar is closed however the loop ends."""
    with progress_bar(total=total, desc=desc, unit=unit, enabled=enabled, last_line=False) as bar:
        for item in items:
            yield item
            bar.update()


class Activity:
    """Long work that is not a loop of steps, as `activity` reports it: `status` is what the
    lines say of how far it has come (the work sets it as it goes)."""

    def __init__(self, desc: str, what: str, *, every: float, grace: float, stream: TextIO) -> None:
        self.desc, self.what, self.stream = desc, what, stream
        self.status = ""
        self.done = 0
        self.started = time.monotonic()
        self._lock = threading.Lock()
        self._ticker = _Ticker(self._line, every, grace)

    def count(self, n: int, total: int, unit: str) -> None:
        """`n` more of `total` `unit` done (callable from any thread): the status says how many."""
        with self._lock:
            self.done += n
            self.status = f"{self.done} of {total} {unit}"

    def _line(self) -> None:
        with self._lock:
            _LineClock.printed()
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
    grace: float = GRACE_SECONDS,
    stream: TextIO | None = None,
) -> Iterator[Activity | None]:
    """Lines "[desc] what" while the block runs, when heartbeat lines are due (the module
    docstring: none within `grace` seconds of its start), with the `Activity.status` the block
    sets, on stderr, terminal or not; None and silence when not `enabled`."""
    if not enabled:
        yield None
        return
    work = Activity(desc, what, every=every, grace=grace, stream=stream if stream is not None else sys.stderr)
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
