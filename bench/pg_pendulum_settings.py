"""Why `train pg --estimator actor-critic` on Pendulum-v1 runs 2-step rollouts on 8 copies.

Each setting below is actor-critic with PGConfig's fields over the shared ones (γ 0.9, GAE(0.95)
unless said, observations and rewards normalised, gradient norm ≤ 0.5, 500k steps). Each run
is evaluated deterministically on 5 episodes (reset seeds 10000 …) every tenth of the budget
and on 10 episodes (seeds 20000 …) at the end. The evaluations draw no random numbers of the
run's, but the run calls no `seed_everything`, so its draws differ from `train pg`'s at the
same seed: another sample of the same setting.

What it shows (figures in bench/RESULTS.md, "Policy gradient (issue 18)"): the number of
updates decides it. Whole episodes or 64-step rollouts never leave −900…−1300; 16-step
rollouts find the swing-up at 150k–250k steps, and the entropy bonus keeps σ up until then.

Usage: python bench/pg_pendulum_settings.py [--settings NAME ...] [--seeds 0] [--steps 500000] [--workers 2]
"""

from __future__ import annotations

import argparse
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from contextlib import closing
from pathlib import Path
from typing import Any

BENCH = Path(__file__).resolve().parent
sys.path.insert(0, str(BENCH.parent))  # run from a checkout without installing the package

SHARED: dict[str, Any] = dict(
    gamma=0.9, normalize_observations=True, normalize_rewards=True, max_grad_norm=0.5, gae_lambda=0.95, value_steps=1
)
# Fields over SHARED; "episodes" is the old preset (whole episodes, no gradient clipping).
SETTINGS: dict[str, dict[str, Any]] = {
    "episodes": dict(
        n_envs=2,
        batch_steps=400,
        learning_rate=1e-2,
        value_learning_rate=3e-3,
        value_steps=20,
        log_std_init=-0.5,
        max_grad_norm=None,
    ),
    "8x8-a": dict(n_envs=8, rollout_steps=8, learning_rate=7e-4, value_learning_rate=1e-3, log_std_init=-2.0, gae_lambda=0.9),
    "8x8-b": dict(n_envs=8, rollout_steps=8, learning_rate=1e-3, value_learning_rate=3e-3, log_std_init=-1.0, gae_lambda=0.9),
    "8x8-c": dict(n_envs=8, rollout_steps=8, learning_rate=3e-3, value_learning_rate=3e-3, value_steps=2, log_std_init=-1.0),
    "8x8-d": dict(n_envs=8, rollout_steps=8, learning_rate=1e-2, value_learning_rate=3e-3, value_steps=2, log_std_init=-1.0),
    "8x8-entropy": dict(
        n_envs=8, rollout_steps=8, learning_rate=1e-3, value_learning_rate=1e-3, log_std_init=-0.5, entropy_coef=0.05
    ),
    "8x8-entropy-fast": dict(
        n_envs=8, rollout_steps=8, learning_rate=3e-3, value_learning_rate=3e-3, log_std_init=-0.5, entropy_coef=0.1
    ),
    "4x4": dict(n_envs=4, rollout_steps=4, learning_rate=1e-3, value_learning_rate=1e-3, log_std_init=-0.5, entropy_coef=0.02),
    "8x2-slow": dict(
        n_envs=8, rollout_steps=2, learning_rate=1e-3, value_learning_rate=1e-3, log_std_init=-0.5, entropy_coef=0.05
    ),
    "8x1": dict(n_envs=8, rollout_steps=1, learning_rate=1e-3, value_learning_rate=1e-3, log_std_init=-0.5, entropy_coef=0.05),
    "8x2-entropy-0.05": dict(
        n_envs=8, rollout_steps=2, learning_rate=2e-3, value_learning_rate=2e-3, log_std_init=-0.5, entropy_coef=0.05
    ),
    "preset": dict(
        n_envs=8, rollout_steps=2, learning_rate=2e-3, value_learning_rate=2e-3, log_std_init=-0.5, entropy_coef=0.1
    ),
}


def one_run(name: str, seed: int, steps: int) -> tuple[str, int, list[tuple[int, float]], float, float]:
    """(name, seed, [(step, evaluated return)] every tenth, final 10-episode return, seconds)."""
    import torch

    from imitation.algorithms.policy_gradient import PGConfig, PolicyGradient
    from imitation.envs.make import make_env
    from imitation.evaluation.policy import evaluate_policy
    from imitation.policies import SingleObservationPolicy

    torch.set_num_threads(1)
    config = PGConfig(env_id="Pendulum-v1", estimator="actor-critic", seed=seed, total_steps=steps, **SHARED | SETTINGS[name])
    learner = PolicyGradient(config)
    points: list[tuple[int, float]] = []
    started = time.perf_counter()
    try:
        with closing(make_env("Pendulum-v1")) as env:
            while not learner.done:
                learner.step()
                if learner.batches % max(1, learner.total // 10) == 0:
                    policy = SingleObservationPolicy(learner.policy)
                    points.append((learner.global_step, evaluate_policy(policy, env, episodes=5, seed=10_000)["mean_return"]))
            final = evaluate_policy(SingleObservationPolicy(learner.policy), env, episodes=10, seed=20_000)["mean_return"]
    finally:
        learner.close()
    return name, seed, points, final, time.perf_counter() - started


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--settings", nargs="+", default=list(SETTINGS), choices=list(SETTINGS), help="settings (default: all)"
    )
    parser.add_argument("--seeds", type=int, nargs="+", default=[0], help="seeds (default: 0)")
    parser.add_argument("--steps", type=int, default=500_000, help="env steps per run (default: 500000)")
    parser.add_argument("--workers", type=int, default=2, help="runs at a time (default: 2, one per core)")
    args = parser.parse_args()
    jobs = [(name, seed, args.steps) for name in args.settings for seed in args.seeds]
    print("| setting | seed | evaluated every tenth (5 episodes) | final (10 episodes) | seconds |")
    print("|---|---:|---|---:|---:|")
    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        for name, seed, points, final, seconds in pool.map(one_run, *zip(*jobs)):
            curve = ", ".join(f"{score:.0f}" for _, score in points)
            print(f"| {name} | {seed} | {curve} | {final:.1f} | {seconds:.0f} |", flush=True)


if __name__ == "__main__":
    main()
