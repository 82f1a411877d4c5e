"""Streams of timestamped samples at their own rates → values on one regular time grid.

A stream is (times, values): int64 ns, non-decreasing, and a (n, k) float64 array. On a grid
time t, `hold` takes the last sample at or before t; `interpolate` draws a straight line between
the samples either side of t (and holds the last one after the end). Where a stream has no value
yet, or its last sample is older than `max_age_ns`, its `default` fills in; without a default
the value is NaN, so the caller starts the grid once every stream without one has a sample.
"""

from __future__ import annotations

import numpy as np

NS = 1_000_000_000


def regular_grid(start_ns: int, end_ns: int, rate_hz: float) -> np.ndarray:
    """Times start, start + 1/rate, … up to end (inclusive), as int64 ns."""
    period_ns = NS / rate_hz
    # The tolerance keeps a time that float division puts a hair short of `end`; it can also admit
    # one a nanosecond past it (a span of 1 s − 1 ns at 1 Hz), which the last line drops.
    count = int(np.floor((end_ns - start_ns) / period_ns + 1e-9)) + 1 if end_ns >= start_ns else 0
    times = start_ns + np.round(np.arange(count) * period_ns).astype(np.int64)
    return times[times <= end_ns]


def hold_index(times: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """Index of the last sample at or before each grid time (-1 before the first): `hold`
    without the values, for streams such as images that are not rows of numbers."""
    return np.searchsorted(times, grid, side="right") - 1


def sample(
    times: np.ndarray,
    values: np.ndarray,
    grid: np.ndarray,
    *,
    align: str,
    default: np.ndarray | None = None,
    max_age_ns: int | None = None,
) -> np.ndarray:
    """The stream's values at each grid time, shape (len(grid), k)."""
    k = values.shape[1]
    fill = default if default is not None else np.full(k, np.nan)
    out = np.empty((len(grid), k), dtype=np.float64)
    last = hold_index(times, grid)
    before = last < 0
    if align == "interpolate" and len(times) > 0:
        for column in range(k):
            out[:, column] = np.interp(grid, times, values[:, column])
    else:
        out[:] = values[np.maximum(last, 0)] if len(times) else fill
    stale = before.copy()
    if max_age_ns is not None and len(times):
        stale |= grid - times[np.maximum(last, 0)] > max_age_ns
    out[stale] = fill
    return out


def split_at_gaps(times: np.ndarray, gap_ns: int) -> list[tuple[int, int]]:
    """(start, end) of each run of `times` (sorted) without a gap longer than `gap_ns`."""
    if len(times) == 0:
        return []
    cuts = np.flatnonzero(np.diff(times) > gap_ns)
    starts = np.concatenate([[0], cuts + 1])
    ends = np.concatenate([cuts, [len(times) - 1]])
    return [(int(times[s]), int(times[e])) for s, e in zip(starts, ends)]


def split_at_markers(start_ns: int, end_ns: int, markers: np.ndarray) -> list[tuple[int, int]]:
    """[start, m1), [m1, m2), …, [mk, end]: each marker time begins a new episode. Ends are given
    1 ns before the next start so no grid time is shared."""
    bounds = [start_ns] + [int(m) for m in markers if start_ns < m <= end_ns] + [end_ns + 1]
    return [(a, b - 1) for a, b in zip(bounds[:-1], bounds[1:]) if b - 1 >= a]
