"""Ray Tune in a process of its own, so that the sweep outlives Ray.

When a Ray process dies (its dashboard agent killed, its raylet out of memory), Ray ends the
driver connected to it at once, from native code: a sweep that ran Tune in its own process
stopped with exit code 1, no message and no table. Here the sweep's process only waits: Tune
runs in a child (its own process group, so that a terminal's Ctrl-C reaches Ray's processes only
as the sweep forwards it), which keeps the sweep's record of its trials (`trials.json`) as it
goes; whatever becomes of the child, the sweep writes the table from that record and says why
it stopped.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import sys
from collections.abc import Callable
from multiprocessing.connection import Connection
from pathlib import Path
from types import FrameType

from imitation.errors import ImitationError
from imitation.jobs.sweep_config import SweepConfig
from imitation.jobs.sweep_trials import SweepTrials
from imitation.ray_engine import ray_session

INTERRUPTED = "interrupted"
RAY_LOG = "ray.log"  # in the sweep's folder: what Ray and Tune printed


def run_apart(
    config: SweepConfig, out: Path, run_train: Callable[[list[str]], None], *, ray_address: str, cpus: int | None
) -> str | None:
    """Run the sweep's unended trials with Tune in a child process. None when Tune ran to its
    end; INTERRUPTED after Ctrl-C (or SIGTERM), forwarded to the child; otherwise why Tune
    stopped early, as one line."""
    context = multiprocessing.get_context("spawn")  # a fresh interpreter: Ray must not inherit this one's threads
    receiver, sender = context.Pipe(duplex=False)
    child = context.Process(
        target=_tune, args=(config, out, run_train, ray_address, cpus, sender), name="imitation sweep (Ray Tune)"
    )
    _track_resources_into(out / RAY_LOG)
    interrupts = 0

    def forward(signum: int, frame: FrameType | None) -> None:
        nonlocal interrupts
        interrupts += 1  # Tune stops its trials at the first, at once at the second
        if child.pid is not None:
            os.kill(child.pid, signal.SIGINT)

    previous = signal.signal(signal.SIGINT, forward)
    try:
        child.start()
        sender.close()
        child.join()
    finally:
        signal.signal(signal.SIGINT, previous)
        if child.is_alive():  # this process is failing: Tune must not go on without it
            child.kill()
    try:
        said = receiver.recv() if receiver.poll() else None
    except EOFError:  # the child ended without a word
        said = None
    if interrupts or said == INTERRUPTED:
        return INTERRUPTED
    if said is not None:
        return said or None
    return (
        f"Ray stopped in the middle of the sweep (its process ended with exit code {child.exitcode}: a Ray process died, "
        "or the machine ran out of memory)"
    )


def _track_resources_into(log_path: Path) -> None:
    """Start multiprocessing's resource tracker with its stderr on the Ray log. A Tune child that
    Ray ends from native code leaves its semaphores behind; the tracker, which outlives this
    process, unlinks them and warns, and that warning would land after the sweep's one-line
    error."""
    from multiprocessing import resource_tracker

    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(log_path, "ab") as log:
            os.dup2(log.fileno(), 2)
            resource_tracker.ensure_running()
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def _tune(
    config: SweepConfig,
    out: Path,
    run_train: Callable[[list[str]], None],
    ray_address: str,
    cpus: int | None,
    report: Connection,
) -> None:
    """The child: Tune over the unended trials; it sends "" when Tune ran to its end, INTERRUPTED,
    or the one line of what stopped it. Its own output, and Ray's (its experiment box, notices,
    a traceback per failed trial, which would bury the sweep's one line per trial) go to
    OUT/ray.log; the lines per trial go where the command's stderr goes."""
    os.setpgid(0, 0)
    lines = os.dup(2)
    with open(out / RAY_LOG, "ab") as log:
        os.dup2(log.fileno(), 1)
        os.dup2(log.fileno(), 2)
    os.environ.setdefault("RAY_AIR_NEW_OUTPUT", "0")
    try:
        trials = SweepTrials.open(out, config, resumed=True)
        with ray_session(ray_address, num_cpus=cpus):
            from imitation.jobs.sweep_tune import run_trials

            run_trials(config, out, run_train, trials, lines)
        report.send(INTERRUPTED if trials.unended() else "")
    except KeyboardInterrupt:
        report.send(INTERRUPTED)
    except ImitationError as error:
        report.send(str(error))
    except Exception as error:  # noqa: BLE001 - Ray's and Tune's own failures, as one line
        report.send(f"Ray Tune failed: {type(error).__name__}: {' '.join(str(error).split())[:300]}")
