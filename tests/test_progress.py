"""Progress reaches a log: when stderr is not a terminal, long work prints plain lines (a
position, the latest figures, the time spent and left) instead of a bar nobody sees."""

from __future__ import annotations

import io

from imitation.progress import ProgressLines, progress_bar


def test_lines_every_interval_and_at_the_end_with_an_estimate() -> None:
    stream = io.StringIO()
    lines = ProgressLines(total=4, desc="BC", unit="epoch", every=0.0, stream=stream)
    with lines:
        for epoch in range(4):
            lines.set_postfix({"train": f"{1.0 / (epoch + 1):.3f}"})
            lines.update()
    written = stream.getvalue().splitlines()
    assert [line.split(":")[0] for line in written] == ["[BC] epoch 1/4", "[BC] epoch 2/4", "[BC] epoch 3/4", "[BC] epoch 4/4"]
    assert written[1].startswith("[BC] epoch 2/4: train 0.500 (") and "left)" in written[1]
    assert "left" not in written[-1] and written[-1].endswith("so far)")


def test_a_quiet_interval_prints_only_the_last_line() -> None:
    stream = io.StringIO()
    lines = ProgressLines(total=3, initial=1, desc="PPO", unit="update", every=3600.0, stream=stream)
    lines.update()
    lines.update()
    assert stream.getvalue().splitlines() == [stream.getvalue().splitlines()[0]] and stream.getvalue().startswith("[PPO] update 3/3 (")


def test_off_a_terminal_the_bar_is_lines_and_disabled_is_silent(capsys) -> None:
    # pytest captures stderr: not a terminal
    assert isinstance(progress_bar(total=2, desc="x", unit="step"), ProgressLines)
    quiet = progress_bar(total=2, desc="x", unit="step", enabled=False)
    quiet.update()
    quiet.close()
    assert capsys.readouterr().err == ""


def test_a_loop_over_items_says_how_far_it_is_while_long_and_nothing_when_quick(capsys, monkeypatch) -> None:
    """convert's and export's loops off a terminal (tqdm alone printed nothing there, and a camera
    bag converted for minutes in silence): heartbeat lines while an item takes long, and no line
    at all for a loop done within a second, so that an error after it is still one line."""
    import time

    from imitation.progress import _LineClock, progress_over

    # A process long started that has printed no progress line yet: its first is due now.
    monkeypatch.setattr(_LineClock, "started", time.monotonic() - 60.0)
    monkeypatch.setattr(_LineClock, "last", None)

    def slow(n: int):
        for k in range(n):
            time.sleep(0.7)
            yield k

    assert list(progress_over(range(5), total=5, desc="read", unit="msg")) == list(range(5))
    assert capsys.readouterr().err == ""
    assert list(progress_over(slow(3), total=3, desc="read", unit="msg")) == [0, 1, 2]
    lines = capsys.readouterr().err.splitlines()
    assert lines and all(line.startswith("[read] msg ") and "so far" in line for line in lines), lines
