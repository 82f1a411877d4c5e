"""Resampling streams onto a regular grid (imitation.data.convert.resample) at the edges: a sample
exactly `max_age_ns` old still counts, one nanosecond older is stale; a grid time equal to a
sample's time holds that sample; interpolation holds the last value past the end; grids, gaps
and markers at their boundaries."""

from __future__ import annotations

import numpy as np
import pytest

from imitation.data.convert.resample import NS, hold_index, regular_grid, sample, split_at_gaps, split_at_markers


def test_a_sample_exactly_max_age_old_is_kept_and_one_nanosecond_older_is_stale() -> None:
    times = np.array([1_000, 2_000], dtype=np.int64)
    values = np.array([[1.0, 10.0], [2.0, 20.0]])
    grid = np.array([999, 1_000, 1_500, 1_501, 2_000, 2_500, 2_501], dtype=np.int64)
    held = sample(times, values, grid, align="hold", default=np.array([-1.0, -2.0]), max_age_ns=500)
    assert held[:, 0].tolist() == [-1.0, 1.0, 1.0, -1.0, 2.0, 2.0, -1.0]
    assert held[:, 1].tolist() == [-2.0, 10.0, 10.0, -2.0, 20.0, 20.0, -2.0]
    # Interpolated values go stale by the age of the last sample at or before the grid time too.
    line = sample(times, values, grid, align="interpolate", max_age_ns=500)
    assert np.isnan(line[0]).all() and np.isnan(line[3]).all() and np.isnan(line[6]).all()
    assert line[[1, 2, 4, 5], 0].tolist() == pytest.approx([1.0, 1.5, 2.0, 2.0])


def test_without_max_age_the_last_sample_is_held_forever_and_nan_fills_before_the_first() -> None:
    times = np.array([100], dtype=np.int64)
    grid = np.array([99, 100, 10**15], dtype=np.int64)
    held = sample(times, np.array([[5.0]]), grid, align="hold")
    assert np.isnan(held[0, 0]) and held[1:, 0].tolist() == [5.0, 5.0]
    assert sample(times, np.array([[5.0]]), grid, align="hold", default=np.array([0.0]))[:, 0].tolist() == [0.0, 5.0, 5.0]


def test_an_empty_stream_is_its_default_everywhere() -> None:
    grid = np.array([0, 1, 2], dtype=np.int64)
    empty = (np.zeros(0, dtype=np.int64), np.zeros((0, 2)))
    for align in ("hold", "interpolate"):
        assert sample(*empty, grid, align=align, default=np.array([3.0, 4.0]), max_age_ns=1).tolist() == [[3.0, 4.0]] * 3
        assert np.isnan(sample(*empty, grid, align=align)).all()


def test_hold_index_takes_the_last_sample_at_or_before_each_time() -> None:
    times = np.array([10, 20, 20, 30], dtype=np.int64)
    assert hold_index(times, np.array([9, 10, 19, 20, 29, 31])).tolist() == [-1, 0, 0, 2, 2, 3]


def test_regular_grid_includes_its_end_and_rounds_each_time_to_the_nanosecond() -> None:
    assert regular_grid(0, NS, 4.0).tolist() == [0, 250_000_000, 500_000_000, 750_000_000, NS]
    assert regular_grid(5, 5, 10.0).tolist() == [5]
    assert regular_grid(10, 5, 10.0).tolist() == []
    # 1/3 s: the times round to the nearest nanosecond, none lost to a float's floor at the end.
    assert regular_grid(0, NS, 3.0).tolist() == [0, 333_333_333, 666_666_667, NS]
    assert regular_grid(7, 7 + NS - 1, 1.0).tolist() == [7]
    # Times before the epoch are times too; the grid is int64 nanoseconds whatever the rate.
    assert regular_grid(-NS, 0, 2.0).tolist() == [-NS, -NS // 2, 0]
    assert regular_grid(10 * NS, 11 * NS, 3.0).dtype == np.int64


def test_gaps_split_only_where_longer_than_the_limit() -> None:
    times = np.array([0, 2, 4, 7, 8], dtype=np.int64)
    assert split_at_gaps(times, 2) == [(0, 4), (7, 8)]
    assert split_at_gaps(times, 3) == [(0, 8)]
    assert split_at_gaps(np.zeros(0, dtype=np.int64), 3) == []
    assert split_at_gaps(np.array([5], dtype=np.int64), 3) == [(5, 5)]


def test_markers_begin_episodes_inside_the_span_only() -> None:
    # A marker at the span's start begins nothing new; one at its end begins a one-time episode;
    # markers outside the span are ignored.
    assert split_at_markers(10, 30, np.array([5, 10, 20, 30, 40])) == [(10, 19), (20, 29), (30, 30)]
    assert split_at_markers(10, 30, np.array([], dtype=np.int64)) == [(10, 30)]
    assert split_at_markers(10, 30, np.array([11])) == [(10, 10), (11, 30)]
    # Two markers at one time begin one episode there, not an empty one between them.
    assert split_at_markers(10, 30, np.array([20, 20])) == [(10, 19), (20, 30)]


def test_a_time_past_the_end_that_rounds_onto_it_is_not_on_the_grid() -> None:
    # At 7 Hz the fifth time is 4/7 s = 571,428,571.43 ns: past an end at 571,428,571 ns, though
    # it rounds to it. The grid holds the times up to the end, as the converter counts its steps.
    end = 571_428_571
    assert regular_grid(0, end, 7.0).tolist() == [0, 142_857_143, 285_714_286, 428_571_429]
    assert regular_grid(0, end + 1, 7.0).tolist() == [0, 142_857_143, 285_714_286, 428_571_429, end]
