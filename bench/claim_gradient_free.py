"""Claim (b) of the notes (§1): gradient-free methods rival policy gradient on small tasks.

Hill climbing and the cross-entropy method (`imitation.algorithms.policy_search`) against
REINFORCE with a baseline and actor-critic (`imitation.algorithms.policy_gradient`) and PPO
(`imitation.algorithms.ppo`), on CartPole-v1 and Pendulum-v1, 5 seeds each. Every method runs
with its env preset (the settings `imitation train …` uses), except that all get the same budget
of env steps (50k on CartPole, 300k on Pendulum, so that `make bench-claims` fits in an hour on
two cores). Along the way each run's policy is evaluated deterministically on 5 episodes
(reset seeds 10 000 …) at eight evenly spaced points of the budget, with the seconds of
training it took to get there (the evaluations themselves are not counted).

It reports each method's evaluated return (mean ± std over seeds):

- at equal env steps: at the end of the budget;
- at equal wall time: at the last evaluation point within W seconds of training, W being the
  mean training time of the fastest method to finish the budget;

and how many seeds reach the task (475 on CartPole, −400 on Pendulum) at an evaluation point,
with the steps and training seconds to the first such point (the finer comparison when every
method ends solved).

Verdict: the claim holds on an env when the better of hill climbing and CEM is within one
standard deviation (over seeds, of the better policy-gradient method) of the best of REINFORCE,
actor-critic and PPO, at equal steps or at equal wall time.

Runs go two at a time in separate processes (one per core; each uses one torch thread).

Usage: python bench/claim_gradient_free.py [--seeds 0 1 2 3 4] [--envs CartPole-v1 Pendulum-v1]
"""

from __future__ import annotations

import argparse
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from contextlib import closing
from pathlib import Path
from typing import Any

import numpy as np

BENCH = Path(__file__).resolve().parent
sys.path.insert(0, str(BENCH.parent))  # run from a checkout without installing the package

BUDGET = {"CartPole-v1": 50_000, "Pendulum-v1": 300_000}
SOLVED = {"CartPole-v1": 475.0, "Pendulum-v1": -400.0}  # the evaluated return that counts as reaching the task
METHODS = ("hill-climb", "cem", "reinforce+baseline", "actor-critic", "ppo")
GRADIENT_FREE = ("hill-climb", "cem")
POINTS = 8
EVAL_EPISODES = 5
EVAL_SEED = 10_000
PLOT = BENCH / "claim_gradient_free.png"


def learner_for(method: str, env_id: str, seed: int) -> Any:
    budget = BUDGET[env_id]
    if method in GRADIENT_FREE:
        from imitation.algorithms.policy_search import PolicySearch
        from imitation.jobs.search import search_config

        return PolicySearch(search_config(env_id, method, total_steps=budget, seed=seed))
    if method == "ppo":
        from imitation.algorithms.ppo import PPO
        from imitation.jobs.presets import ppo_config

        return PPO(ppo_config(env_id, total_steps=budget, seed=seed))
    from imitation.algorithms.policy_gradient import PolicyGradient
    from imitation.jobs.pg import pg_config

    estimator = "baseline" if method == "reinforce+baseline" else "actor-critic"
    return PolicyGradient(pg_config(env_id, estimator=estimator, total_steps=budget, seed=seed))


def one_run(method: str, env_id: str, seed: int) -> dict[str, Any]:
    """(steps, training seconds, evaluated return) at each evaluation point of one run."""
    import torch

    from imitation.envs.make import make_env
    from imitation.evaluation.policy import evaluate_policy
    from imitation.policies import SingleObservationPolicy
    from imitation.seeding import seed_everything

    torch.set_num_threads(1)
    seed_everything(seed)
    learner = learner_for(method, env_id, seed)
    budget = BUDGET[env_id]
    points: list[tuple[float, float, float]] = []
    next_point = budget / POINTS
    try:
        with closing(make_env(env_id)) as env:
            while not learner.done:
                learner.step()
                if learner.global_step >= next_point or learner.done:
                    policy = SingleObservationPolicy(learner.policy)
                    score = evaluate_policy(policy, env, episodes=EVAL_EPISODES, seed=EVAL_SEED)["mean_return"]
                    points.append((float(learner.global_step), learner.clock.seconds, float(score)))
                    while next_point <= learner.global_step:
                        next_point += budget / POINTS
    finally:
        learner.close()
    return {"method": method, "env": env_id, "seed": seed, "points": points}


def at_wall_time(points: list[tuple[float, float, float]], seconds: float) -> float:
    within = [score for _, elapsed, score in points if elapsed <= seconds]
    return within[-1] if within else float("nan")


def first_reaching(points: list[tuple[float, float, float]], threshold: float) -> tuple[float, float]:
    """(steps, seconds) of the first evaluation point at or above `threshold`; (nan, nan) if none."""
    for steps, seconds, score in points:
        if score >= threshold:
            return steps, seconds
    return float("nan"), float("nan")


def summarise(env_id: str, runs: list[dict[str, Any]], seeds: list[int]) -> bool:
    by_method = {method: [run for run in runs if run["method"] == method] for method in METHODS}
    final = {method: np.array([run["points"][-1][2] for run in per]) for method, per in by_method.items()}
    seconds = {method: np.array([run["points"][-1][1] for run in per]) for method, per in by_method.items()}
    steps = {method: np.array([run["points"][-1][0] for run in per]) for method, per in by_method.items()}
    wall = float(min(value.mean() for value in seconds.values()))
    at_wall = {method: np.array([at_wall_time(run["points"], wall) for run in per]) for method, per in by_method.items()}
    print(f"\n### {env_id}: {BUDGET[env_id]:,} env steps each, {len(seeds)} seeds; equal wall time W = {wall:.0f} s\n")
    threshold = SOLVED[env_id]
    print(
        f"| method | steps used | training time (s) | return at equal steps | return at W | per seed (equal steps) | "
        f"seeds reaching {threshold:g} | steps to it (mean) | seconds to it (mean) |"
    )
    print("|---|---:|---:|---:|---:|---|---:|---:|---:|")
    for method in METHODS:
        reached = np.array([first_reaching(run["points"], threshold) for run in by_method[method]])
        hits = int(np.isfinite(reached[:, 0]).sum())
        to_steps = f"{np.nanmean(reached[:, 0]):,.0f}" if hits else "—"
        to_seconds = f"{np.nanmean(reached[:, 1]):.0f}" if hits else "—"
        print(
            f"| {method} | {steps[method].mean():,.0f} | {seconds[method].mean():.0f} | {final[method].mean():.1f} ± "
            f"{final[method].std():.1f} | {np.nanmean(at_wall[method]):.1f} ± {np.nanstd(at_wall[method]):.1f} | "
            f"{', '.join(f'{value:.0f}' for value in final[method])} | {hits}/{len(reached)} | {to_steps} | {to_seconds} |"
        )
    verdict = False
    for label, scores in (("equal steps", final), ("equal wall time", at_wall)):
        free = max(GRADIENT_FREE, key=lambda method: np.nanmean(scores[method]))
        gradient = max((m for m in METHODS if m not in GRADIENT_FREE), key=lambda method: np.nanmean(scores[method]))
        margin = np.nanmean(scores[gradient]) - np.nanmean(scores[free])
        rivals = bool(margin <= np.nanstd(scores[gradient]))
        verdict |= rivals
        print(
            f"{label}: best gradient-free {free} {np.nanmean(scores[free]):.1f}, best policy gradient {gradient} "
            f"{np.nanmean(scores[gradient]):.1f}: {'rivals' if rivals else 'does not rival'}"
        )
    return verdict


def plot(runs: list[dict[str, Any]], envs: list[str], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(len(envs), 2, figsize=(11, 3.8 * len(envs)), dpi=80, squeeze=False)
    colours = dict(zip(METHODS, ("tab:green", "tab:olive", "tab:blue", "tab:purple", "tab:orange")))
    for row, env_id in enumerate(envs):
        for method in METHODS:
            per = [run["points"] for run in runs if run["env"] == env_id and run["method"] == method]
            length = min(len(points) for points in per)
            array = np.array([points[:length] for points in per])  # seeds × points × (steps, seconds, return)
            for column, axis_index in enumerate((0, 1)):
                axes[row, column].plot(
                    array[:, :, axis_index].mean(axis=0),
                    array[:, :, 2].mean(axis=0),
                    marker="o",
                    color=colours[method],
                    label=method,
                )
        axes[row, 0].set_xlabel("env steps")
        axes[row, 1].set_xlabel("training seconds")
        for column in range(2):
            axes[row, column].set_ylabel("evaluated return (mean over seeds)")
            axes[row, column].set_title(env_id)
            axes[row, column].grid(True, alpha=0.3)
        axes[row, 0].legend(loc="lower right")
    figure.tight_layout()
    figure.savefig(path)
    plt.close(figure)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4], help="seeds (default: 0 1 2 3 4)")
    parser.add_argument("--envs", nargs="+", default=list(BUDGET), choices=list(BUDGET), help="envs (default: both)")
    parser.add_argument("--workers", type=int, default=2, help="runs at a time (default: 2, one per core)")
    parser.add_argument(
        "--plot", type=Path, default=PLOT, help=f"where the plot goes (default: {PLOT.relative_to(BENCH.parent)})"
    )
    args = parser.parse_args()
    started = time.perf_counter()
    jobs = [(method, env_id, seed) for env_id in args.envs for seed in args.seeds for method in METHODS]
    runs: list[dict[str, Any]] = []
    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        for run in pool.map(one_run, *zip(*jobs)):
            runs.append(run)
            print(
                f"{run['env']} {run['method']} seed {run['seed']}: {run['points'][-1][2]:.1f} ({time.perf_counter() - started:.0f} s)",
                flush=True,
            )
    verdicts = {env_id: summarise(env_id, [run for run in runs if run["env"] == env_id], args.seeds) for env_id in args.envs}
    print()
    for env_id, holds in verdicts.items():
        print(
            f"verdict (b), {env_id}: gradient-free methods rival policy gradient: {'holds' if holds else 'does not hold here'}"
        )
    plot(runs, args.envs, args.plot)
    print(f"plot: {args.plot}")
    print(f"total runtime: {time.perf_counter() - started:.0f} s")


if __name__ == "__main__":
    main()
