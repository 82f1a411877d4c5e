"""Benchmark: offline BC on the real robot recordings with and without the previous action as an
input (`train bc --previous-action on|off`), beside the trivial baselines `train bc` reports.

Everything goes through the CLI as a user runs it: `convert` of ../shared/testdata's turtlesim bag
(two command streams, at 10 Hz, the maps of tests/algorithms/test_bc_robot_logs.py) and Unitree G1
LeRobot v2.1 set, then `train bc` at default settings but for --previous-action. Prints one row
per dataset and setting: the held-out NLL / MSE per step, each baseline's, which baselines BC
beats, and the training time (bench/RESULTS.md, "Real robot logs").

    .venv/bin/python bench/bc_previous_action.py [--datasets teleop follower g1]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO / "tests"))
from algorithms.test_bc_robot_logs import FOLLOWER_MAP, TELEOP_MAP  # noqa: E402
from support import TESTDATA, write_map  # noqa: E402

BAG = TESTDATA / "ros1" / "plotjuggler_example.bag"
SOURCES = {"teleop": (BAG, TELEOP_MAP), "follower": (BAG, FOLLOWER_MAP), "g1": (TESTDATA / "lerobot" / "g1_v21", None)}


def cli(*args: str) -> None:
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "OMP_NUM_THREADS": "1"}
    subprocess.run([sys.executable, str(REPO / "cli.py"), *args], check=True, env=env, stdout=subprocess.DEVNULL)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--datasets", nargs="+", choices=sorted(SOURCES), default=sorted(SOURCES))
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench-bc-previous-") as folder:
        work = Path(folder)
        for name in args.datasets:
            source, recording_map = SOURCES[name]
            demos = work / f"{name}.mcap"
            convert_map = ["--map", str(write_map(work, recording_map, f"{name}.yaml"))] if recording_map else []
            cli("convert", str(source), *convert_map, "--out", str(demos), "--quiet")
            for setting in ("off", "on"):
                run = work / f"bc-{name}-{setting}"
                started = time.perf_counter()
                cli("train", "bc", "--demos", str(demos), "--previous-action", setting, "--out", str(run), "--quiet")
                seconds = time.perf_counter() - started
                metrics = json.loads((run / "metrics.json").read_text())
                scores = metrics["validation"]
                baselines = "; ".join(
                    f"{base} {value['nll']:.3f} / {value['mse']:.4g}" for base, value in metrics["baselines"].items()
                )
                beaten = ", ".join(base for base, won in metrics["beats_baselines"].items() if won) or "none"
                print(
                    f"{name:8} previous action {setting:3}: BC {scores['nll']:.3f} / {scores['mse']:.4g} (NLL / MSE); "
                    f"{baselines}; beats {beaten}; best epoch {metrics['best_epoch']} of {metrics['epochs']}; {seconds:.0f} s",
                    flush=True,
                )


if __name__ == "__main__":
    main()
