"""Benchmark: our PPO vs stable-baselines3's PPO, and our time per step beside its floors.

For each environment, with rl-baselines3-zoo's tuned hyperparameters on both sides:

- wall time until the mean return of the last 20 finished training episodes first reaches the
  target (CartPole-v1: 475, Pendulum-v1: -250), checked after every update on both sides, and
  env-steps/s over the whole fixed-length run (100k steps CartPole, 200k Pendulum);
- our time per env step split into env stepping, rollout inference and updates (the PPO learner's own
  timers), each beside its floor: stepping the same vector env with random actions, no-grad
  forward passes of the same actor and critic, and a bare forward/backward/FlatAdam loop of the same
  count and minibatch size.

Every training run and the floors run in a fresh process (bench/ppo_worker.py), one at a time,
with OMP_NUM_THREADS=1 and torch.set_num_threads(1); ours and SB3 alternate seed by seed so that
load from other work falls on both. Clocks start just before the env and model are built, so
interpreter start-up and imports are excluded. SB3 runs from its own venv, bench/.venv-sb3,
which is created on first use with the same Python and the same torch, gymnasium and numpy
versions as ours.

Targets (issue): ours ≤ 0.5× SB3's time to target, ≥ 2× its steps/s, each part ≤ 1.5× its floor.
"""

from __future__ import annotations

import argparse
import importlib.metadata
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import ppo_worker

BENCH = Path(__file__).resolve().parent
ROOT = BENCH.parent
SB3_VENV = BENCH / ".venv-sb3"
SB3_VERSION = "2.9.2"  # pinned so that figures stay comparable from run to run
THREADS = 1  # torch and OpenMP threads for every process (the machine has 2 cores)
WINDOW = 20  # finished training episodes in the running mean that must reach the target
TIME_TARGET = 0.5  # ours / SB3 wall time to target, at most
SPEED_TARGET = 2.0  # ours / SB3 env-steps per second, at least
FLOOR_TARGET = 1.5  # each part of ours / its floor, at most
PARTS = ("env", "inference", "update")


@dataclass(frozen=True)
class EnvBench:
    """One environment: rl-baselines3-zoo's hyperparameters (hyperparams/ppo.yml), run length, target."""

    key: str
    env_id: str
    zoo: dict[str, Any]
    total_steps: int
    target: float


BENCHES = {
    bench.key: bench
    for bench in (
        EnvBench(
            "cartpole",
            "CartPole-v1",
            dict(
                n_envs=8, n_steps=32, batch_size=256, gae_lambda=0.8, gamma=0.98, n_epochs=20,
                ent_coef=0.0, learning_rate="lin_0.001", clip_range="lin_0.2",
            ),
            total_steps=100_000,
            target=475.0,
        ),
        EnvBench(
            "pendulum",
            "Pendulum-v1",
            # batch_size is not in the zoo entry: SB3's default 64 applies, written out for ours.
            dict(
                n_envs=4, n_steps=1024, batch_size=64, gae_lambda=0.95, gamma=0.9, n_epochs=10,
                ent_coef=0.0, learning_rate=1e-3, clip_range=0.2, use_sde=True, sde_sample_freq=4,
            ),
            total_steps=200_000,
            target=-250.0,
        ),
    )
}


# ------------------------------------------------------------------------------------------------
# The SB3 venv and the worker processes


def _installed_versions(python: Path, packages: list[str]) -> dict[str, str | None]:
    """Versions of `packages` as `python` sees them (None where one is missing)."""
    code = (
        "import importlib.metadata as m, json, sys\n"
        "def v(name):\n"
        "    try: return m.version(name)\n"
        "    except m.PackageNotFoundError: return None\n"
        "print(json.dumps({name: v(name) for name in sys.argv[1:]}))"
    )
    completed = subprocess.run([str(python), "-c", code, *packages], capture_output=True, text=True, check=True)
    return json.loads(completed.stdout)


def ensure_sb3_venv() -> Path:
    """The interpreter of bench/.venv-sb3, created and filled first if it is missing or stale.

    Its torch, gymnasium and numpy are pinned to the versions of the interpreter running this
    script, so that both sides run the same kernels and the same environment code."""
    wanted = {
        "stable-baselines3": SB3_VERSION,
        "torch": importlib.metadata.version("torch"),
        "gymnasium": importlib.metadata.version("gymnasium"),
        "numpy": importlib.metadata.version("numpy"),
    }
    python = SB3_VENV / "bin" / "python"
    if not python.exists():
        # sys._base_executable is the interpreter this venv was made from: the same Python version.
        base = sys._base_executable
        print(f"bench/ppo.py: creating {SB3_VENV.relative_to(ROOT)} with {base}", flush=True)
        subprocess.run([base, "-m", "venv", str(SB3_VENV)], check=True)
    if _installed_versions(python, list(wanted)) != wanted:
        pins = [f"{name}=={version}" for name, version in wanted.items()]
        print(f"bench/ppo.py: pip install {' '.join(pins)} into {SB3_VENV.relative_to(ROOT)} (first time: a few minutes)", flush=True)
        subprocess.run([str(python), "-m", "pip", "install", "--quiet", "--disable-pip-version-check", *pins], check=True)
    return python


def run_worker(python: Path, mode: str, spec: dict[str, Any], workdir: Path) -> dict[str, Any]:
    """Run bench/ppo_worker.py MODE on spec in a fresh process and return its result."""
    spec_path, result_path = workdir / "spec.json", workdir / "result.json"
    spec_path.write_text(json.dumps(spec))
    result_path.unlink(missing_ok=True)
    env = dict(os.environ, OMP_NUM_THREADS=str(THREADS), MKL_NUM_THREADS=str(THREADS))
    if mode != "sb3":
        # The SB3 venv must not see our package; ours and the floors import it from the checkout.
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    command = [str(python), str(BENCH / "ppo_worker.py"), mode, str(spec_path), str(result_path)]
    completed = subprocess.run(command, cwd=ROOT, env=env, capture_output=True, text=True)
    if completed.returncode != 0:
        raise SystemExit(f"bench/ppo.py: {mode} worker failed ({completed.returncode}):\n{completed.stderr[-4000:]}")
    return json.loads(result_path.read_text())


# ------------------------------------------------------------------------------------------------
# Running one environment's benchmark


def measure(bench: EnvBench, seeds: list[int], total_steps: int, floor_repeats: int, sb3_python: Path, workdir: Path) -> dict[str, Any]:
    """Ours and SB3 for each seed, then the floors `floor_repeats` times.

    Which side goes first alternates from seed to seed, so neither always follows the other."""
    base_spec = dict(env_id=bench.env_id, zoo=bench.zoo, total_steps=total_steps, target=bench.target, window=WINDOW, threads=THREADS)
    runs: dict[str, list[dict[str, Any]]] = {"ours": [], "sb3": []}
    sides = [("ours", Path(sys.executable)), ("sb3", sb3_python)]
    for number, seed in enumerate(seeds):
        for side, python in sides if number % 2 == 0 else sides[::-1]:
            run = run_worker(python, side, dict(base_spec, seed=seed), workdir)
            runs[side].append(run)
            mark = reaching(run, bench.target)
            reached = f"{mark[0]:.1f} s ({mark[1]:,.0f} steps)" if mark is not None else "not reached"
            print(
                f"  {bench.env_id} {side:4} seed {seed}: {run['seconds']:6.1f} s, {run['steps_per_second']:7.0f} steps/s, "
                f"time to {bench.target:g}: {reached}, final mean return {run['final_return']:.1f}",
                flush=True,
            )
    floors = []
    for repeat in range(floor_repeats):
        floor = run_worker(Path(sys.executable), "floors", dict(base_spec, seed=repeat), workdir)
        floors.append(floor)
        print(
            f"  {bench.env_id} floors {repeat + 1}/{floor_repeats}: env {floor['seconds_env']:.2f} s, "
            f"inference {floor['seconds_inference']:.2f} s, update {floor['seconds_update']:.2f} s",
            flush=True,
        )
    return {
        "env_id": bench.env_id, "n_envs": bench.zoo["n_envs"], "target": bench.target, "seeds": seeds,
        "total_steps": total_steps, "runs": runs, "floors": floors,
    }


# ------------------------------------------------------------------------------------------------
# Figures and tables


def reaching(run: dict[str, Any], target: float) -> tuple[float, float] | None:
    """(seconds, env steps) of the first update after which the run's mean return was ≥ target."""
    for seconds, steps, mean_return in run["marks"]:
        if not math.isnan(mean_return) and mean_return >= target:
            return seconds, steps
    return None


def _to_target(runs: list[dict[str, Any]], target: float, index: int) -> list[float]:
    """Seconds (index 0) or steps (index 1) to target per run; inf where the target was not reached."""
    return [math.inf if (mark := reaching(run, target)) is None else mark[index] for run in runs]


def _verdict(passed: bool | None) -> str:
    return "n/a" if passed is None else ("PASS" if passed else "FAIL")


def figures(result: dict[str, Any]) -> dict[str, Any]:
    """Medians, ratios and verdicts of one environment's measurements."""
    ours, sb3 = result["runs"]["ours"], result["runs"]["sb3"]
    time_ours = statistics.median(_to_target(ours, result["target"], 0))
    time_sb3 = statistics.median(_to_target(sb3, result["target"], 0))
    if math.isinf(time_ours) and math.isinf(time_sb3):
        time_ratio, time_pass = math.nan, None  # neither reached the target: nothing to compare
    else:
        time_ratio = time_ours / time_sb3 if time_sb3 > 0 else math.inf
        time_pass = time_ratio <= TIME_TARGET
    speed_ours = statistics.median(run["steps_per_second"] for run in ours)
    speed_sb3 = statistics.median(run["steps_per_second"] for run in sb3)
    floors = result["floors"]
    transitions = floors[0]["vector_steps"] * result["n_envs"]
    parts = {}
    for part in PARTS:
        mine = statistics.median(run[f"seconds_{part}"] / run["steps"] for run in ours) * 1e6
        floor = statistics.median(f[f"seconds_{part}"] for f in floors) / transitions * 1e6
        parts[part] = {"ours_us": mine, "floor_us": floor, "ratio": mine / floor, "pass": mine / floor <= FLOOR_TARGET}
    sb3_split = {
        "rollout_us": statistics.median(run["seconds_rollout"] / run["steps"] for run in sb3) * 1e6,
        "update_us": statistics.median(run["seconds_update"] / run["steps"] for run in sb3) * 1e6,
    }
    return {
        "time_ratio": time_ratio, "time_pass": time_pass, "speed_sb3": speed_sb3, "speed_ratio": speed_ours / speed_sb3,
        "speed_pass": speed_ours / speed_sb3 >= SPEED_TARGET, "parts": parts, "sb3_split": sb3_split,
        "gradient_steps": floors[0]["gradient_steps"], "vector_steps": floors[0]["vector_steps"],
    }


def _table(headers: list[str], rows: list[list[str]], markdown: bool) -> list[str]:
    """Rows as a markdown table, or as aligned text columns."""
    if markdown:
        lines = ["| " + " | ".join(headers) + " |", "|" + "|".join("---" if i == 0 else "---:" for i in range(len(headers))) + "|"]
        return lines + ["| " + " | ".join(row) + " |" for row in rows]
    widths = [max(len(cell) for cell in column) for column in zip(headers, *rows)]

    def render(cells: list[str]) -> str:
        return "  ".join(cell.ljust(width) if i == 0 else cell.rjust(width) for i, (cell, width) in enumerate(zip(cells, widths)))

    return [render(headers), render(["-" * w for w in widths])] + [render(row) for row in rows]


def _reached(value: float) -> str:
    """Seconds or steps to target as a cell: one decimal below 1000, thousands separated above."""
    if math.isinf(value):
        return "not reached"
    return f"{value:.1f}" if value < 1000 else f"{value:,.0f}"


def report(result: dict[str, Any], markdown: bool) -> list[str]:
    """Tables and verdicts for one environment."""
    fig = figures(result)
    ours, sb3 = result["runs"]["ours"], result["runs"]["sb3"]
    target = result["target"]
    lines = [
        f"{result['env_id']}: {ours[0]['steps']:,} env steps per run, target: mean of the last {WINDOW} "
        f"training episodes ≥ {target:g}; {THREADS} torch/OpenMP thread; seeds {', '.join(map(str, result['seeds']))}",
        "",
    ]
    headers = ["", *(f"seed {seed}" for seed in result["seeds"]), "median"]
    rows = []
    for side, runs in (("ours", ours), ("SB3", sb3)):
        seconds = _to_target(runs, target, 0)
        rows.append([f"{side}: seconds to {target:g}", *map(_reached, seconds), _reached(statistics.median(seconds))])
    for side, runs in (("ours", ours), ("SB3", sb3)):
        steps = _to_target(runs, target, 1)
        rows.append([f"{side}: env steps to {target:g}", *map(_reached, steps), _reached(statistics.median(steps))])
    for side, runs in (("ours", ours), ("SB3", sb3)):
        speeds = [run["steps_per_second"] for run in runs]
        rows.append([f"{side}: env-steps/s", *(f"{s:,.0f}" for s in speeds), f"{statistics.median(speeds):,.0f}"])
    for side, runs in (("ours", ours), ("SB3", sb3)):
        returns = [run["final_return"] for run in runs]
        rows.append([f"{side}: final mean return", *(f"{r:.1f}" for r in returns), f"{statistics.median(returns):.1f}"])
    lines += _table(headers, rows, markdown) + [""]

    time_ratio = "n/a (neither side reached the target)" if math.isnan(fig["time_ratio"]) else f"{fig['time_ratio']:.2f}×"
    lines += _table(
        ["target", "ours / SB3", "verdict"],
        [
            [f"time to {target:g} ≤ {TIME_TARGET}× SB3", time_ratio, _verdict(fig["time_pass"])],
            [f"env-steps/s ≥ {SPEED_TARGET}× SB3", f"{fig['speed_ratio']:.2f}×", _verdict(fig["speed_pass"])],
        ],
        markdown,
    ) + [""]

    rows = []
    for part in PARTS:
        p = fig["parts"][part]
        rows.append([part, f"{p['ours_us']:.1f}", f"{p['floor_us']:.1f}", f"{p['ratio']:.2f}×", _verdict(p["pass"])])
    total_ours = sum(fig["parts"][part]["ours_us"] for part in PARTS)
    total_floor = sum(fig["parts"][part]["floor_us"] for part in PARTS)
    rows.append(["total", f"{total_ours:.1f}", f"{total_floor:.1f}", f"{total_ours / total_floor:.2f}×", ""])
    lines += [
        f"Our time per env step (µs, median of seeds) beside its floor (median of {len(result['floors'])} runs); "
        f"{fig['vector_steps']:,} vector steps, {fig['gradient_steps']:,} gradient steps; target ≤ {FLOOR_TARGET}×:",
        "",
    ]
    lines += _table(["part", "ours µs/step", "floor µs/step", "ours / floor", "verdict"], rows, markdown) + [""]
    split = fig["sb3_split"]
    lines += [
        f"SB3 for comparison (µs per env step): rollouts (env + inference + GAE) {split['rollout_us']:.1f}, "
        f"updates {split['update_us']:.1f}. With all three parts at their floors ours would run "
        f"{1e6 / fig['speed_sb3'] / total_floor:.2f}× SB3's env-steps/s.",
        "",
    ]
    return lines


def _positive(text: str) -> int:
    """argparse type: an integer of at least 1."""
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def parse_seeds(text: str, keys: list[str]) -> dict[str, list[int]]:
    """`3` (seeds 0-2 everywhere) or `cartpole=3,pendulum=2` (3 for any not named) → {env key: seeds}."""
    if "=" not in text:
        return {key: list(range(_positive(text))) for key in keys}
    counts = {name: _positive(count) for name, count in (item.split("=", 1) for item in text.split(","))}
    unknown = set(counts) - set(BENCHES)
    if unknown:
        raise ValueError(f"unknown environment(s) {', '.join(sorted(unknown))}")
    return {key: list(range(counts.get(key, 3))) for key in keys}


def run_all(keys: list[str], seeds: dict[str, list[int]], steps: int | None, floor_repeats: int) -> dict[str, Any]:
    """Every measurement of the chosen environments, with the benchmark's time and the versions used."""
    sb3_python = ensure_sb3_venv()
    started = time.perf_counter()
    print(f"bench/ppo.py: every process runs with OMP_NUM_THREADS={THREADS} and torch.set_num_threads({THREADS}), one at a time", flush=True)
    for key in keys:
        _, gaps = ppo_worker.ours_config_kwargs(BENCHES[key].zoo)
        for gap in gaps:
            print(f"  note ({BENCHES[key].env_id}): zoo {gap}; SB3 runs the zoo value", flush=True)
    results = []
    with tempfile.TemporaryDirectory(prefix="bench-ppo-") as workdir:
        for key in keys:
            bench = BENCHES[key]
            results.append(measure(bench, seeds[key], steps or bench.total_steps, floor_repeats, sb3_python, Path(workdir)))
    versions = _installed_versions(sb3_python, ["stable-baselines3", "torch", "gymnasium", "numpy"])
    return {"results": results, "seconds": time.perf_counter() - started, "versions": versions}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--envs", default="cartpole,pendulum", help=f"comma-separated, of {', '.join(BENCHES)} (default: both)")
    parser.add_argument("--seeds", default="3", help="seeds per environment: N, or e.g. cartpole=3,pendulum=2 (default 3)")
    parser.add_argument("--steps", type=_positive, help="env steps per run for every environment (default: 100000 CartPole, 200000 Pendulum)")
    parser.add_argument("--floor-repeats", type=_positive, default=3, help="runs of each floor (default 3)")
    parser.add_argument("--json", type=Path, help="also write every measurement to this file")
    parser.add_argument("--markdown", type=Path, help="also write the tables as markdown to this file")
    parser.add_argument("--from-json", type=Path, help="run nothing: print the tables of a file written by --json")
    args = parser.parse_args(argv)
    keys = args.envs.split(",")
    unknown = [key for key in keys if key not in BENCHES]
    if unknown:
        parser.error(f"--envs: unknown {', '.join(unknown)}; known: {', '.join(BENCHES)}")

    if args.from_json:
        if not args.from_json.is_file():
            parser.error(f"--from-json: no file {args.from_json}")
        measured = json.loads(args.from_json.read_text())
    else:
        for key in keys:
            rollout = BENCHES[key].zoo["n_envs"] * BENCHES[key].zoo["n_steps"]
            if args.steps is not None and args.steps < rollout:
                parser.error(f"--steps {args.steps} is less than one {BENCHES[key].env_id} rollout ({rollout} steps)")
        try:
            seeds = parse_seeds(args.seeds, keys)
        except (ValueError, argparse.ArgumentTypeError) as error:
            parser.error(f"--seeds {args.seeds}: {error}")
        measured = run_all(keys, seeds, args.steps, args.floor_repeats)
    print()
    for result in measured["results"]:
        print("\n".join(report(result, markdown=False)))
    versions = ", ".join(f"{name} {version}" for name, version in measured["versions"].items())
    print(f"benchmark time: {measured['seconds'] / 60:.1f} min; {versions}")
    if args.markdown:
        args.markdown.write_text("\n".join(line for result in measured["results"] for line in report(result, markdown=True)))
    if args.json:
        args.json.write_text(json.dumps(measured, indent=1))


if __name__ == "__main__":
    main()
