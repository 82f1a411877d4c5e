"""Benchmark: expert labels that take-over DAgger, classic DAgger and BC need on CartPole-v1.

Each side runs as a user would type it, through the command line, 3 seeds:

- take-over (HG-DAgger): `train dagger --env CartPole-v1 --expert standin --mode takeover
  --rounds 5`. The stand-in (a scripted person) takes the controls when the pole leans past
  0.1 rad and hands them back below 0.02; only the steps it drove are labels.
- classic DAgger: `train dagger --env CartPole-v1 --expert scripted --rounds 5`, where the
  scripted controller labels every visited state (β: 1, 0.8, …, 0.2).
- BC: `record --expert scripted --episodes N` then `train bc` on those N episodes, for
  N = 1, 2, 5, 10: every recorded step is a label.

For each, the labels used when the learner first reaches a return of 475 (of 500) on the run's
deterministic evaluation (DAgger: after each round; BC: the run's final evaluation), and the
intervention rate round by round for take-over. Results are printed as a table; figures go in
bench/RESULTS.md.

Usage: python bench/dagger_takeover.py [--seeds 0 1 2]
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

BENCH = Path(__file__).resolve().parent
CLI = [sys.executable, str(BENCH.parent / "cli.py")]
TARGET = 475.0
BC_EPISODES = (1, 2, 5, 10)


def imitation(*args: str) -> dict:
    """Run `imitation ARGS --json --quiet`; its JSON result."""
    result = subprocess.run(
        [*CLI, *args, "--json", "--quiet"], capture_output=True, text=True, env={**os.environ, "OMP_NUM_THREADS": "1"}
    )
    if result.returncode != 0:
        raise SystemExit(f"imitation {' '.join(args)} failed: {result.stderr[-2000:]}")
    return json.loads(result.stdout.strip().splitlines()[-1])


def dagger(folder: Path, seed: int, *extra: str) -> dict:
    """A 5-round DAgger run: labels and evaluation return after each round, and when it first reached the target."""
    out = folder / f"dagger-{'-'.join(extra)}-{seed}"
    started = time.perf_counter()
    imitation("train", "dagger", "--env", "CartPole-v1", "--rounds", "5", "--seed", str(seed), "--out", str(out), *extra)
    with open(out / "progress.csv") as rows:
        history = list(csv.DictReader(rows))
    labels = [int(float(row["expert_labels"])) for row in history]
    returns = [float(row["return"]) for row in history]
    reached = next((labels[i] for i, value in enumerate(returns) if value >= TARGET), None)
    rates = [float(row["intervention_rate"]) for row in history]
    return {"labels": labels, "returns": returns, "rates": rates, "reached": reached, "seconds": time.perf_counter() - started}


def behavioural_cloning(folder: Path, seed: int) -> dict:
    """BC on N scripted episodes for growing N: labels and final return per budget."""
    started = time.perf_counter()
    budgets = []
    for episodes in BC_EPISODES:
        demos = folder / f"bc-{seed}-{episodes}.mcap"
        recorded = imitation("record", "--env", "CartPole-v1", "--expert", "scripted", "--episodes", str(episodes),
                             "--seed", str(1000 + 100 * seed), "--out", str(demos))
        run = imitation("train", "bc", "--demos", str(demos), "--env", "CartPole-v1", "--seed", str(seed),
                        "--out", str(folder / f"bc-{seed}-{episodes}"))
        labels = round(recorded["mean_return"] * episodes)  # CartPole pays 1 a step: the return is the length
        budgets.append((labels, run["eval"]["mean_return"]))
    reached = next((labels for labels, value in budgets if value >= TARGET), None)
    return {"budgets": budgets, "reached": reached, "seconds": time.perf_counter() - started}


def shown(values: list) -> str:
    return ", ".join("-" if value is None else f"{value:g}" for value in values)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="dagger-takeover-") as tmp:
        folder = Path(tmp)
        takeover = [dagger(folder, seed, "--expert", "standin", "--mode", "takeover") for seed in args.seeds]
        classic = [dagger(folder, seed, "--expert", "scripted") for seed in args.seeds]
        cloning = [behavioural_cloning(folder, seed) for seed in args.seeds]
    print(f"CartPole-v1, seeds {args.seeds}: expert labels when the learner first returns >= {TARGET:g} (- : not within the runs)")
    print(f"  take-over DAgger (standin): {shown([run['reached'] for run in takeover])}")
    print(f"  classic DAgger (scripted):  {shown([run['reached'] for run in classic])}")
    print(f"  BC (scripted demos):        {shown([run['reached'] for run in cloning])}")
    for name, runs in (("take-over", takeover), ("classic", classic)):
        for seed, run in zip(args.seeds, runs):
            print(f"  {name} seed {seed}: labels by round {shown(run['labels'])}; return {shown(run['returns'])}; "
                  f"expert drove {', '.join(f'{100 * rate:.1f} %' for rate in run['rates'])} of steps; {run['seconds']:.0f} s")
    for seed, run in zip(args.seeds, cloning):
        print(f"  BC seed {seed}: (labels, return) {run['budgets']}; {run['seconds']:.0f} s")


if __name__ == "__main__":
    main()
