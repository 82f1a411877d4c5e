"""Benchmark: our behavioural cloning vs HumanCompatibleAI/imitation 1.0.1's BC.

Both sides fit the same MLP (separate actor/critic trunks of [32,32] or [256,256], ReLU, Adam at
lr 1e-3, batch 256) to the same 49,527 (s, a) pairs of the CartPole expert in
shared/testdata/experts/expert_cartpole.npz, and report:

- training samples/s: epochs × transitions trained on / wall time of the training call alone
  (ours: `BehaviouralCloning(...)` and `fit` on it; theirs: `BC.train(n_epochs=...)`), policy and data building excluded, the
  median of --repeats fresh processes with one torch/OpenMP thread. Each process makes two
  identical calls, each with a fresh policy: "cold" is the first, which pays one-time lazy
  initialisation (theirs: torch.optim.Adam's first construction imports torch._dynamo, about
  1 s, while it builds its policy, outside its timed call; ours uses imitation.flat_adam and no
  torch.optim), "warm" the second, steady-state training;
- the return each reaches: a separate run of --return-epochs epochs, then 10 deterministic
  CartPole-v1 episodes reset with seeds 0..9.

Each side keeps its own defaults beyond that: theirs adds its entropy bonus (ent_weight 1e-3)
and computes the critic in every loss; ours normalises observations, keeps the weights of the
epoch with the lowest training loss (no validation split) and has no entropy term.

Theirs runs from bench/.venv-imitation (Python 3.11, gymnasium 0.29, torch 2.13.0 CPU), made on
first use, through bench/bc_peer.py; ours runs this file's worker mode from the main venv.
Target (issue): ours ≥ 3× their samples/s at an equal or better mean return, judged on each
timing.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

BENCH = Path(__file__).resolve().parent
ROOT = BENCH.parent
DATA = ROOT.parent / "shared" / "testdata" / "experts" / "expert_cartpole.npz"
PEER_VENV = BENCH / ".venv-imitation"
PEER_VERSION = "1.0.1"
# imitation 1.0.1 needs gymnasium 0.29, which has no wheels for our Python 3.12 stack's numpy.
PEER_BASE_PYTHON = "/root/.pyenv/versions/3.11.7/bin/python3"
# The CPU build on local disk; a bare `torch` requirement would resolve a multi-GB CUDA build.
PEER_TORCH = "torch==2.13.0"
NETWORKS = ([32, 32], [256, 256])
BATCH_SIZE = 256
SPEED_TARGET = 3.0
THREADS = 1  # torch and OpenMP threads in every worker (the machine has 2 cores)


# ------------------------------------------------------------------------------------------------
# The peer venv and the worker processes


def _peer_versions(python: Path) -> dict[str, str] | None:
    """imitation's, gymnasium's and torch's versions in the peer venv, or None if it is broken."""
    probe = (
        "import importlib.metadata as m, json, imitation, gymnasium, torch;"
        "print(json.dumps({n: m.version(n) for n in ('imitation', 'gymnasium', 'torch', 'stable-baselines3')}))"
    )
    completed = subprocess.run([str(python), "-c", probe], capture_output=True, text=True, cwd=BENCH, env=_peer_env())
    return json.loads(completed.stdout) if completed.returncode == 0 else None


def _peer_env() -> dict[str, str]:
    """The environment of peer processes: one thread, and none of our checkout on the path."""
    env = dict(os.environ, OMP_NUM_THREADS=str(THREADS), MKL_NUM_THREADS=str(THREADS))
    env.pop("PYTHONPATH", None)
    return env


def ensure_imitation_venv() -> tuple[Path | None, str]:
    """bench/.venv-imitation's interpreter, created or repaired first; (None, why) if impossible."""
    python = PEER_VENV / "bin" / "python"
    if python.exists() and (versions := _peer_versions(python)) and versions["imitation"] == PEER_VERSION:
        return python, f"imitation {versions['imitation']}, gymnasium {versions['gymnasium']}, torch {versions['torch']}, stable-baselines3 {versions['stable-baselines3']}"
    base = PEER_BASE_PYTHON if Path(PEER_BASE_PYTHON).exists() else shutil.which("python3.11")
    if base is None:
        return None, f"no Python 3.11 found ({PEER_BASE_PYTHON} nor python3.11 on PATH); imitation {PEER_VERSION} needs it"
    steps = []
    if not python.exists():
        print(f"bench/bc.py: creating {PEER_VENV.relative_to(ROOT)} with {base}", flush=True)
        steps.append([base, "-m", "venv", str(PEER_VENV)])
    print(f"bench/bc.py: pip install {PEER_TORCH}, then imitation=={PEER_VERSION} into {PEER_VENV.relative_to(ROOT)} (first time: a few minutes)", flush=True)
    pip = [str(python), "-m", "pip", "install", "--quiet", "--disable-pip-version-check"]
    steps += [pip + [PEER_TORCH], pip + [f"imitation=={PEER_VERSION}"]]
    for step in steps:
        completed = subprocess.run(step, capture_output=True, text=True)
        if completed.returncode != 0:
            return None, f"`{' '.join(step)}` failed ({completed.returncode}): {completed.stderr.strip()[-1500:]}"
    versions = _peer_versions(python)
    if versions is None or versions["imitation"] != PEER_VERSION:
        return None, f"imitation {PEER_VERSION} installed but does not import in {PEER_VENV.relative_to(ROOT)}"
    return python, f"imitation {versions['imitation']}, gymnasium {versions['gymnasium']}, torch {versions['torch']}, stable-baselines3 {versions['stable-baselines3']}"


def run_worker(side: str, spec: dict[str, Any], peer_python: Path | None) -> dict[str, Any]:
    """One training run of `side` ('ours' or 'theirs') in a fresh process; its result dict."""
    with tempfile.TemporaryDirectory(prefix="bench-bc-") as workdir:
        spec_path, result_path = Path(workdir) / "spec.json", Path(workdir) / "result.json"
        spec_path.write_text(json.dumps(spec))
        if side == "ours":
            env = dict(os.environ, OMP_NUM_THREADS=str(THREADS), MKL_NUM_THREADS=str(THREADS))
            env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
            command = [sys.executable, str(Path(__file__).resolve()), "--worker", str(spec_path), str(result_path)]
        else:
            env = _peer_env()
            command = [str(peer_python), str(BENCH / "bc_peer.py"), str(spec_path), str(result_path)]
        # cwd=BENCH keeps the repo root off the peer's sys.path, so `imitation` is theirs there.
        completed = subprocess.run(command, cwd=BENCH, env=env, capture_output=True, text=True)
        if completed.returncode != 0:
            raise SystemExit(f"bench/bc.py: {side} worker failed ({completed.returncode}):\n{completed.stderr[-4000:]}")
        return json.loads(result_path.read_text())


# ------------------------------------------------------------------------------------------------
# Our side (runs in the worker process)


def _our_transitions(path: str) -> Any:
    """The SB2-format expert npz as our TransitionTensors (s' left out: BC does not read it)."""
    import torch

    from imitation.data.loader import TransitionTensors

    data = np.load(path)
    starts = data["episode_starts"].astype(bool)
    ends = np.append(starts[1:], True)
    episode_index = np.cumsum(starts) - 1
    lengths = np.bincount(episode_index)
    # CartPole-v1 truncates at 500 steps; a shorter episode ended by termination.
    truncated = ends & (lengths[episode_index] >= 500)
    return TransitionTensors(
        observations=torch.from_numpy(data["obs"].astype(np.float32)),
        actions=torch.from_numpy(data["actions"].reshape(-1).astype(np.int64)),
        rewards=torch.from_numpy(data["rewards"].astype(np.float32)),
        next_observations=None,
        terminated=torch.from_numpy(ends & ~truncated),
        truncated=torch.from_numpy(truncated),
        episode_index=torch.from_numpy(episode_index.astype(np.int64)),
    )


def our_worker(spec: dict[str, Any]) -> dict[str, Any]:
    """Build the data and, per run, the policy (untimed); time each BC training (the learner,
    whose Adam is built in it, and `fit`); evaluate the last."""
    # Imported here, in the worker process only: the driver stays free of torch and of our package.
    import gymnasium as gym
    import torch

    from imitation.algorithms.bc import BCConfig, BehaviouralCloning, fit, policy_options
    from imitation.evaluation.policy import evaluate_policy
    from imitation.policies import SingleObservationPolicy, make_policy

    torch.set_num_threads(THREADS)
    train = _our_transitions(spec["data"])
    epochs = spec["epochs"]
    config = BCConfig(
        hidden_sizes=list(spec["hidden_sizes"]),
        batch_size=spec["batch_size"],
        validation_fraction=0.0,
        epochs=epochs,
        patience=epochs,
        seed=spec["seed"],
        device="cpu",
        threads=THREADS,
    )
    env = gym.make("CartPole-v1")
    speeds = []
    # Identical runs with a fresh policy each: the first pays one-time lazy initialisation (cold),
    # the later ones show steady-state training speed (warm).
    for _ in range(spec["runs"]):
        torch.manual_seed(spec["seed"])
        policy = make_policy(env.observation_space, env.action_space, **policy_options(config))
        started = time.perf_counter()
        learner = BehaviouralCloning(policy, train, None, config)
        fit(learner)
        speeds.append(epochs * len(train) / (time.perf_counter() - started))
    out: dict[str, Any] = {"samples_per_second": speeds}
    if spec["eval_episodes"] > 0:
        out["returns"] = evaluate_policy(SingleObservationPolicy(learner.policy), env, episodes=spec["eval_episodes"], seed=0)["returns"]
    env.close()
    return out


# ------------------------------------------------------------------------------------------------
# The benchmark


def _positive(text: str) -> int:
    """argparse type: an integer of at least 1."""
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def benchmark(args: argparse.Namespace, peer_python: Path | None) -> list[dict[str, Any]]:
    """For each network: each side's cold and warm samples/s per repeat, and its returns."""
    sides = ["ours"] + (["theirs"] if peer_python is not None else [])
    rows = []
    for hidden in NETWORKS:
        speeds: dict[str, dict[str, list[float]]] = {side: {"cold": [], "warm": []} for side in sides}
        for repeat in range(args.repeats):
            # Sides alternate within a repeat so that load from other work falls on both.
            for side in sides:
                spec = {"data": str(DATA), "hidden_sizes": hidden, "batch_size": BATCH_SIZE, "epochs": args.epochs, "runs": 2, "seed": repeat, "eval_episodes": 0}
                cold, warm = run_worker(side, spec, peer_python)["samples_per_second"]
                speeds[side]["cold"].append(cold)
                speeds[side]["warm"].append(warm)
                print(f"  {hidden} {side} repeat {repeat + 1}/{args.repeats}: cold {cold:,.0f}, warm {warm:,.0f} samples/s", flush=True)
        returns = {}
        for side in sides:
            spec = {"data": str(DATA), "hidden_sizes": hidden, "batch_size": BATCH_SIZE, "epochs": args.return_epochs, "runs": 1, "seed": 0, "eval_episodes": args.eval_episodes}
            returns[side] = run_worker(side, spec, peer_python)["returns"]
            print(f"  {hidden} {side} after {args.return_epochs} epochs: mean return {np.mean(returns[side]):.1f}", flush=True)
        rows.append({"network": hidden, "speeds": speeds, "returns": returns})
    return rows


def table(rows: list[dict[str, Any]]) -> tuple[str, dict[str, bool | None]]:
    """The markdown table, and per timing ('warm', 'cold') whether every network meets the target
    (None without theirs)."""
    lines = [
        "| network | timing | ours samples/s | theirs samples/s | ratio | ours return | theirs return | ≥3× at ≥ return |",
        "|---|---|---:|---:|---:|---:|---:|---|",
    ]
    verdicts: dict[str, list[bool]] = {"warm": [], "cold": []}
    for row in rows:
        ours_return = float(np.mean(row["returns"]["ours"]))
        theirs_return = float(np.mean(row["returns"]["theirs"])) if "theirs" in row["returns"] else None
        for timing in ("warm", "cold"):
            ours_speed = statistics.median(row["speeds"]["ours"][timing])
            if theirs_return is not None:
                theirs_speed = statistics.median(row["speeds"]["theirs"][timing])
                ratio = ours_speed / theirs_speed
                passed = ratio >= SPEED_TARGET and ours_return >= theirs_return
                verdicts[timing].append(passed)
                cells = [f"{theirs_speed:,.0f}", f"{ratio:.2f}×", f"{ours_return:.1f}", f"{theirs_return:.1f}", "PASS" if passed else "FAIL"]
            else:
                cells = ["—", "—", f"{ours_return:.1f}", "—", "— (no peer)"]
            lines.append(f"| {row['network']} | {timing} | {ours_speed:,.0f} | " + " | ".join(cells) + " |")
    return "\n".join(lines), {timing: (all(passed) if passed else None) for timing, passed in verdicts.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--epochs", type=_positive, default=5, help="epochs of each timed run, both sides (default 5)")
    parser.add_argument("--repeats", type=_positive, default=3, help="timed runs per side and network; the median counts (default 3)")
    parser.add_argument("--return-epochs", type=_positive, default=20, help="epochs of the run whose policy is evaluated (default 20)")
    parser.add_argument("--eval-episodes", type=_positive, default=10, help="deterministic CartPole-v1 episodes, seeds 0..N-1 (default 10)")
    parser.add_argument("--ours-only", action="store_true", help="skip the peer venv and benchmark ours alone")
    parser.add_argument("--worker", nargs=2, metavar=("SPEC", "RESULT"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        spec_path, result_path = args.worker
        Path(result_path).write_text(json.dumps(our_worker(json.loads(Path(spec_path).read_text()))))
        return
    if not DATA.exists():
        raise SystemExit(f"bench/bc.py: skipped: the expert data {DATA} is absent (it lives in shared/, outside the repo)")
    started = time.perf_counter()
    peer_python, peer_note = (None, "skipped (--ours-only)") if args.ours_only else ensure_imitation_venv()
    print(f"bench/bc.py: HumanCompatibleAI/imitation: {peer_note}", flush=True)
    print(f"bench/bc.py: batch {BATCH_SIZE}, {args.epochs} epochs × {args.repeats} repeats timed, returns after {args.return_epochs} epochs over {args.eval_episodes} episodes", flush=True)
    markdown, verdicts = table(benchmark(args, peer_python))
    print()
    print(markdown)
    print()
    for timing, verdict in verdicts.items():
        summary = {True: "PASS: ours ≥ 3× theirs at an equal or better return on every network", False: "FAIL: see the rows marked FAIL", None: "no verdict: theirs did not run"}[verdict]
        print(f"{timing}: {summary}")
    print(f"({time.perf_counter() - started:.0f} s)")


if __name__ == "__main__":
    main()
