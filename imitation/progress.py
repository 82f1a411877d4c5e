"""Progress that reaches the user whether stderr is a terminal or a log file.

tqdm draws its bar only on a terminal (`disable=None`), so a job whose output goes to a file or
a pipe (a batch script, CI, `nohup`) used to say nothing for minutes. `progress_bar` gives tqdm's
bar on a terminal and otherwise `ProgressLines`: a plain line every 30 seconds and one at the end,
with the position, the latest figures, the time spent and an estimate of the time left.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Iterable, Iterator
from typing import Any, TextIO

from tqdm import tqdm


class ProgressLines:
    """Progress for a log rather than a terminal: a plain line every `every` seconds and one at
    the end. It has the part of tqdm's interface the toolkit uses (update, set_postfix, close, a
    context manager)."""

    def __init__(
        self, *, total: int, initial: int = 0, desc: str, unit: str, every: float = 30.0, stream: TextIO | None = None
    ) -> None:
        self.total, self.count, self.desc, self.unit, self.every = total, initial, desc, unit, every
        self.stream = stream if stream is not None else sys.stderr
        self.started = self.last = time.monotonic()
        self.first = self.shown = initial
        self.postfix = ""

    def set_postfix(self, values: dict[str, str], refresh: bool = True) -> None:
        self.postfix = ", ".join(f"{key} {value}" for key, value in values.items())

    def update(self, n: int = 1) -> None:
        self.count += n
        now = time.monotonic()
        if now - self.last >= self.every or self.count >= self.total:
            self.last = now
            self._line(now)

    def _line(self, now: float, *, final: bool = False) -> None:
        self.shown = self.count
        spent = now - self.started
        done = self.count - self.first
        left = spent / done * (self.total - self.count) if done else float("nan")
        eta = f", about {_duration(left)} left" if self.count < self.total and left == left and not final else ""
        figures = f": {self.postfix}" if self.postfix else ""
        print(
            f"[{self.desc}] {self.unit} {self.count}/{self.total}{figures} ({_duration(spent)} so far{eta})",
            file=self.stream,
            flush=True,
        )

    def close(self) -> None:
        """The last line, when the work ended before its total (an early stop) or between lines."""
        if self.count != self.shown:
            self._line(time.monotonic(), final=True)

    def __enter__(self) -> ProgressLines:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def _duration(seconds: float) -> str:
    return f"{seconds:.0f} s" if seconds < 120 else f"{seconds / 60:.1f} min"


def progress_bar(*, total: int, initial: int = 0, desc: str, unit: str, enabled: bool = True) -> Any:
    """A tqdm bar on a terminal; on anything else (a log file, a pipe) `ProgressLines`; nothing
    when not `enabled`."""
    if enabled and not sys.stderr.isatty():
        return ProgressLines(total=total, initial=initial, desc=desc, unit=unit)
    return tqdm(total=total, initial=initial, desc=desc, unit=unit, disable=not enabled, dynamic_ncols=True)


def progress_iter[T](iterable: Iterable[T], *, total: int, desc: str, unit: str, enabled: bool = True) -> Iterator[T]:
    """`iterable`, with progress shown as `progress_bar` shows it."""
    with progress_bar(total=total, desc=desc, unit=unit, enabled=enabled) as bar:
        for item in iterable:
            yield item
            bar.update()
