"""Claim (d) of the notes (§4, PPO): clipping works as well as the adaptive KL penalty, and the
adaptive penalty holds the KL per update around its target.

The notes give PPO two ways to keep π_{k+1} near π_k:

- the adaptive penalty L(θ) − β D̄_KL(θ‖θ_k), with β doubled when D̄_KL ≥ 1.5δ and halved when
  D̄_KL ≤ δ/1.5 ("adapts quickly"), so that D̄_KL stays around the target δ;
- the clipped objective, "simple to implement but works well compared to KL penalty".

This script trains the bundled PPO with each objective on CartPole-v1 (50k steps) and
Pendulum-v1 (100k steps), 5 seeds each (two runs at a time, one per core), every other setting the env's preset (rl-baselines3-zoo's
where known; δ = 0.01, β_0 = 1), and records, per update, the training return, the mean KL
between the policy before and after the update, and β. It reports:

- the final return: each run's policy evaluated deterministically on 10 episodes (reset seeds
  0–9), mean ± std over seeds;
- the KL per update: its median and 90th percentile over the second half of training, and, for
  the penalty, the share of updates whose KL lies in [δ/1.5, 1.5δ] (the band where β holds still);
- β over training (plotted).

Verdicts: "clipping works as well" holds on an env when the clip runs' mean final return is at
least the penalty runs' minus the standard error of the difference; "the penalty holds KL around
δ" holds when the median KL of the penalty runs lies within [δ/2, 2δ].

Usage: python bench/claim_clip_vs_kl.py [--seeds 0 1 2 3 4] [--envs CartPole-v1 Pendulum-v1]
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from contextlib import closing
from pathlib import Path

import numpy as np
import torch

BENCH = Path(__file__).resolve().parent
sys.path.insert(0, str(BENCH.parent))  # run from a checkout without installing the package

from imitation.algorithms.ppo import PPO  # noqa: E402
from imitation.envs.make import make_env  # noqa: E402
from imitation.evaluation.policy import evaluate_policy  # noqa: E402
from imitation.jobs.loop import run as run_learner  # noqa: E402
from imitation.jobs.presets import ppo_config  # noqa: E402
from imitation.policies import SingleObservationPolicy  # noqa: E402
from imitation.seeding import seed_everything  # noqa: E402

STEPS = {"CartPole-v1": 50_000, "Pendulum-v1": 100_000}
OBJECTIVES = ("clip", "kl")
PLOT = BENCH / "claim_clip_vs_kl.png"

Run = dict[str, np.ndarray | float]


def train(env_id: str, objective: str, seed: int) -> Run:
    torch.set_num_threads(1)
    seed_everything(seed)
    config = ppo_config(env_id, objective=objective, seed=seed, total_steps=STEPS[env_id])
    learner = PPO(config)
    try:
        rows = run_learner(learner)
    finally:
        learner.close()
    with closing(make_env(env_id)) as env:
        final = evaluate_policy(SingleObservationPolicy(learner.policy.cpu()), env, episodes=10, seed=0)["mean_return"]
    return {
        "step": np.array([row["step"] for row in rows]),
        "return": np.array([row["return"] for row in rows]),
        "kl": np.array([row["kl"] for row in rows]),
        "beta": np.array([row["kl_beta"] for row in rows]),
        "final": float(final),
        "target": config.kl_target,
    }


def second_half(values: np.ndarray) -> np.ndarray:
    return values[len(values) // 2 :]


def summarise(env_id: str, runs: dict[str, list[Run]]) -> dict[str, bool]:
    print(f"\n### {env_id} ({STEPS[env_id]:,} steps, {len(runs['clip'])} seeds)\n")
    print(
        "| objective | final return, mean ± std | per seed | KL median (2nd half) | KL p90 | share of updates with KL in [δ/1.5, 1.5δ] |"
    )
    print("|---|---:|---|---:|---:|---:|")
    target = float(runs["kl"][0]["target"])
    for objective, per_seed in runs.items():
        finals = np.array([run["final"] for run in per_seed])
        kls = np.concatenate([second_half(np.asarray(run["kl"])) for run in per_seed])
        in_band = np.mean((kls >= target / 1.5) & (kls <= 1.5 * target))
        print(
            f"| {objective} | {finals.mean():.1f} ± {finals.std():.1f} | {', '.join(f'{f:.1f}' for f in finals)} | "
            f"{np.median(kls):.4f} | {np.percentile(kls, 90):.4f} | {in_band:.2f} |"
        )
    clip = np.array([run["final"] for run in runs["clip"]])
    kl = np.array([run["final"] for run in runs["kl"]])
    standard_error = math.sqrt(clip.var(ddof=1) / len(clip) + kl.var(ddof=1) / len(kl)) if len(clip) > 1 else 0.0
    median_kl = float(np.median(np.concatenate([second_half(np.asarray(run["kl"])) for run in runs["kl"]])))
    verdicts = {
        "clipping works as well as the penalty": bool(clip.mean() >= kl.mean() - standard_error),
        "the penalty holds KL around δ": bool(target / 2 <= median_kl <= 2 * target),
    }
    print(
        f"\nclip − penalty final return: {clip.mean() - kl.mean():+.1f} (standard error {standard_error:.1f}); "
        f"median KL under the penalty {median_kl:.4f} against δ = {target}"
    )
    return verdicts


def plot(results: dict[str, dict[str, list[Run]]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(len(results), 3, figsize=(13, 3.6 * len(results)), dpi=80, squeeze=False)
    colours = {"clip": "tab:blue", "kl": "tab:orange"}
    for row, (env_id, runs) in enumerate(results.items()):
        for objective, per_seed in runs.items():
            for index, run in enumerate(per_seed):
                label = objective if index == 0 else None
                axes[row, 0].plot(run["step"], run["return"], color=colours[objective], alpha=0.6, label=label)
                axes[row, 1].plot(run["step"], run["kl"], color=colours[objective], alpha=0.6, label=label)
                if objective == "kl":
                    axes[row, 2].plot(run["step"], run["beta"], color=colours[objective], alpha=0.6)
        target = float(runs["kl"][0]["target"])
        axes[row, 1].axhline(target, color="grey", linestyle="--", linewidth=1, label="δ")
        axes[row, 1].set_yscale("log")
        axes[row, 2].set_yscale("log")
        for column, title in enumerate(("training return", "KL(π_k ‖ π_k+1) per update", "β (penalty runs)")):
            axes[row, column].set_title(f"{env_id}: {title}")
            axes[row, column].set_xlabel("env steps")
            axes[row, column].grid(True, alpha=0.3)
        axes[row, 0].legend(loc="lower right")
        axes[row, 1].legend(loc="upper right")
    figure.tight_layout()
    figure.savefig(path)
    plt.close(figure)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4], help="seeds (default: 0 1 2 3 4)")
    parser.add_argument("--envs", nargs="+", default=list(STEPS), choices=list(STEPS), help="envs (default: both)")
    parser.add_argument("--workers", type=int, default=2, help="runs at a time (default: 2, one per core)")
    parser.add_argument(
        "--plot", type=Path, default=PLOT, help=f"where the plot goes (default: {PLOT.relative_to(BENCH.parent)})"
    )
    args = parser.parse_args()
    started = time.perf_counter()
    results: dict[str, dict[str, list[Run]]] = {env_id: {objective: [] for objective in OBJECTIVES} for env_id in args.envs}
    jobs = [(env_id, objective, seed) for env_id in args.envs for seed in args.seeds for objective in OBJECTIVES]
    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        for (env_id, objective, seed), run in zip(jobs, pool.map(train, *zip(*jobs))):
            results[env_id][objective].append(run)
            print(f"{env_id} {objective} seed {seed}: {run['final']:.1f} ({time.perf_counter() - started:.0f} s)", flush=True)
    verdicts = {env_id: summarise(env_id, runs) for env_id, runs in results.items()}
    print()
    for env_id, per_claim in verdicts.items():
        for claim, holds in per_claim.items():
            print(f"verdict (d), {env_id}: {claim}: {'holds' if holds else 'does not hold here'}")
    plot(results, args.plot)
    print(f"plot: {args.plot}")
    print(f"total runtime: {time.perf_counter() - started:.0f} s")


if __name__ == "__main__":
    main()
