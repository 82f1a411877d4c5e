"""Benchmark: `train bc` on 480×640 camera frames, as a user runs it with stderr going to a log.

Data: `imitation record --env CartPole-v1 --expert scripted --pixels 480x640 --episodes E` (real
rendered frames, PNG, written once and cached under --data-dir). The measurement runs the command
line given after `--` (default: `train bc --demos DATA --env CartPole-v1 --epochs 1`) in a fresh
process whose stderr is a pipe (not a terminal, so progress comes as plain lines), timestamps every
line it prints, and stops it after --limit seconds if it has not finished. Reported: exit code,
seconds to the first line, the longest silence between lines (and after the last one, for a run
stopped at the limit), the process's peak RSS (ru_maxrss of the one child, read after it exits or
is killed), when the resident size sampled twice a second peaked, and its wall time. With
--interrupt-after S it presses Ctrl-C (SIGINT) S seconds in and reports how long the command took
to stop after it.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

BENCH = Path(__file__).resolve().parent
REPO = BENCH.parent
DEFAULT_ARGS = ["train", "bc", "--demos", "DATA", "--env", "CartPole-v1", "--epochs", "1"]


def record(data: Path, episodes: int) -> None:
    """The demo file, recorded once."""
    if data.exists():
        return
    data.parent.mkdir(parents=True, exist_ok=True)
    record = ["record", "--env", "CartPole-v1", "--expert", "scripted", "--pixels", "480x640", "--quiet", "--episodes"]
    subprocess.run([sys.executable, str(REPO / "cli.py"), *record, str(episodes), "--out", str(data)], check=True)


def measure(command: list[str], limit: float, interrupt_after: float | None = None) -> dict[str, object]:
    """Run `command`, its stderr a pipe; the lines' times, the silences, peak RSS; Ctrl-C
    `interrupt_after` seconds in, if given."""
    started = time.monotonic()
    child = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=REPO)
    lines: list[tuple[float, str]] = []

    def read() -> None:
        assert child.stderr is not None
        for line in child.stderr:
            lines.append((time.monotonic() - started, line.rstrip()))

    samples: list[tuple[float, int]] = []  # (seconds, resident MB), twice a second

    def sample() -> None:
        while child.poll() is None:
            try:
                status = Path(f"/proc/{child.pid}/status").read_text()
            except OSError:
                break
            resident = next((int(line.split()[1]) for line in status.splitlines() if line.startswith("VmRSS:")), 0)
            samples.append((time.monotonic() - started, resident // 1024))
            time.sleep(0.5)

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    interrupted_at = None
    try:
        if interrupt_after is not None:
            try:
                child.wait(timeout=interrupt_after)
            except subprocess.TimeoutExpired:
                child.send_signal(signal.SIGINT)
                interrupted_at = time.monotonic() - started
        code = child.wait(timeout=limit)
        stopped = False
    except subprocess.TimeoutExpired:
        child.kill()
        code = child.wait()
        stopped = True
    wall = time.monotonic() - started
    reader.join(timeout=5)
    sampler.join(timeout=5)
    peak_at = max(samples, key=lambda sample: sample[1]) if samples else (0.0, 0)
    rss_mb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    times = [t for t, _ in lines]
    gaps = [b - a for a, b in zip([0.0, *times], [*times, wall] if stopped else times)]
    return {
        "exit": code,
        "stopped_at_limit": stopped,
        "wall_s": round(wall, 1),
        "first_line_s": round(times[0], 1) if times else None,
        "longest_silence_s": round(max(gaps), 1) if gaps else round(wall, 1),
        "lines": len(lines),
        **({"stopped_after_ctrl_c_s": round(wall - interrupted_at, 1)} if interrupted_at is not None else {}),
        "peak_rss_mb": round(rss_mb),
        "sampled_peak": f"{peak_at[1]} MB at {peak_at[0]:.1f} s",
        "first_lines": [f"{t:.1f} s: {text}" for t, text in lines[:4]],
        "last_lines": [f"{t:.1f} s: {text}" for t, text in lines[-3:]],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data-dir", type=Path, default=Path("/tmp/bench_bc_pixels_progress"))
    parser.add_argument("--episodes", type=int, default=3, help="episodes recorded (500 steps each)")
    parser.add_argument("--limit", type=float, default=300.0, help="seconds before the run is stopped")
    parser.add_argument("--interrupt-after", type=float, metavar="S", help="press Ctrl-C S seconds in")
    parser.add_argument("args", nargs=argparse.REMAINDER, help="-- then the imitation arguments (DATA stands for the file)")
    options = parser.parse_args()
    data = options.data_dir / f"cartpole-480x640-{options.episodes}.mcap"
    record(data, options.episodes)
    args = [a for a in options.args if a != "--"] or DEFAULT_ARGS
    out = options.data_dir / "run"
    args = [str(data) if a == "DATA" else str(out) if a == "OUT" else a for a in args]
    for stale in (out, Path(f"{out}.partial")):
        if stale.exists():
            subprocess.run(["rm", "-rf", str(stale)], check=True)
    command = [sys.executable, str(REPO / "cli.py"), *args]
    if "--out" not in args:
        command += ["--out", str(out)]
    result = measure(command, options.limit, options.interrupt_after)
    print(json.dumps({"command": " ".join(["imitation", *args]), **result}, indent=1))
    os.sync()


if __name__ == "__main__":
    main()
