"""Benchmark: DAgger against behavioural cloning, return against the number of expert labels.

The theory notes (§5.1) claim that BC suffers from compounding error: it is trained on the
expert's state distribution only, so once its small mistakes take it off that distribution it
meets states it has no data for, and its errors grow with the horizon (∝ T² rather than ∝ T).
DAgger labels the states the learner itself visits, so it should reach expert-level return with
fewer expert-labelled samples. This script measures that.

Task: Pendulum-v1 with the scripted expert (`imitation.experts.scripted.pendulum`). The
swing-up is where compounding bites: a slightly mistimed pump leaves the pendulum at an
(angle, speed) pair the expert never passed through, and the learner's next action there is a
guess. CartPole's expert stays within a small region that BC covers after a few hundred labels,
so the gap there is narrower (the pilot that chose the task: bench/RESULTS.md). Pendulum
episodes also always last 200 steps, so every episode costs exactly 200 labels on both sides and
the label axes line up.

- BC: for each budget of n expert episodes (collect_round with β = 1, i.e. pure expert rollouts),
  a fresh policy is trained with BC (`BehaviouralCloning`, run to its end) on their 200·n labelled steps.
- DAgger: the `DAgger` learner with one episode per round and the exponential schedule β_i = 0.5^(i-1):
  round 1 is a pure expert rollout (the seed set), later rounds mostly follow the learner. After
  each round it records the cumulative expert labels and the learner's return.
- Both use the same policy (64×64 tanh MLP, normalised observations) and the same BCConfig.
  Neither holds out a validation episode, because with one or two episodes that would discard
  half the labels; early stopping therefore watches the training loss. BC trains from scratch at
  each budget; DAgger warm-starts each round from the previous learner, as the `DAgger` learner does.
- Every policy, the expert and a uniform-random policy are evaluated deterministically on the
  same 10 episodes (reset seeds 10_000 …). Normalised return = (R - R_random) / (R_expert - R_random).

Usage: python bench/dagger_vs_bc.py [--seeds 1 2 3] [--quick]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch

BENCH = Path(__file__).resolve().parent
sys.path.insert(0, str(BENCH.parent))  # run from a checkout without installing the package

from imitation.algorithms.bc import BCConfig, BehaviouralCloning, fit, policy_options  # noqa: E402
from imitation.algorithms.dagger import DAgger, DAggerConfig, collect_round  # noqa: E402
from imitation.data.loader import transitions_to_torch  # noqa: E402
from imitation.data.types import episodes_to_transitions  # noqa: E402
from imitation.envs.make import make_env  # noqa: E402
from imitation.evaluation.policy import evaluate_policy  # noqa: E402
from imitation.experts.scripted import scripted_expert  # noqa: E402
from imitation.jobs.loop import run as run_learner  # noqa: E402
from imitation.policies import ActorCritic, SingleObservationPolicy, make_policy  # noqa: E402

ENV_ID = "Pendulum-v1"
EVAL_EPISODES = 10
EVAL_SEED = 10_000
TARGET = 0.95  # normalised return the methods race to
BC_EPISODES = (1, 2, 3, 4, 6, 8, 12, 16, 24)
DAGGER_ROUNDS = 12
QUICK_BC_EPISODES = (1, 2, 4, 8)
QUICK_DAGGER_ROUNDS = 5
PLOT = BENCH / "dagger_vs_bc.png"

Curve = list[tuple[int, float]]  # (expert labels, raw return)


def bc_config(seed: int) -> BCConfig:
    """The BC settings both methods share: a small MLP, a quick fit, no validation hold-out."""
    return BCConfig(
        epochs=100, patience=20, batch_size=64, learning_rate=1e-3, hidden_sizes=[64, 64],
        activation="tanh", validation_fraction=0.0, seed=seed, device="cpu", threads=1,
    )


def random_policy(env: Any, seed: int) -> Callable[[Any], Any]:
    """Uniformly random actions from a seeded generator, so R_random is reproducible."""
    env.action_space.seed(seed)
    return lambda _observation: env.action_space.sample()


def mean_return(policy: Callable[[Any], Any], env: Any) -> float:
    return evaluate_policy(policy, env, episodes=EVAL_EPISODES, seed=EVAL_SEED)["mean_return"]


def bc_curve(env: Any, expert: Callable[[Any], Any], seed: int, budgets: tuple[int, ...]) -> Curve:
    """BC from scratch on the first n of one set of expert episodes, for each n in `budgets`."""
    rng = np.random.default_rng(seed)
    # Reset seeds 50_000 + 100_000·seed … stay clear of DAgger's (100_000·seed + 1_000·round)
    # and of the evaluation seeds.
    episodes = collect_round(
        env, None, expert, beta=1.0, episodes=max(budgets), seed=seed * 100_000 + 50_000, rng=rng, metadata={"source": "expert"}
    )
    curve = []
    for n in budgets:
        config = bc_config(seed)
        policy = make_policy(env.observation_space, env.action_space, **policy_options(config))
        train = transitions_to_torch(episodes_to_transitions(episodes[:n], next_observations=False))
        learner = BehaviouralCloning(policy, train, None, config)
        fit(learner)
        curve.append((len(train), mean_return(SingleObservationPolicy(learner.policy), env)))
    return curve


def dagger_curve(env: Any, expert: Callable[[Any], Any], seed: int, rounds: int) -> Curve:
    """DAgger, one episode a round; the learner's return after each round."""
    config = DAggerConfig(rounds=rounds, episodes_per_round=1, beta_schedule="exponential", beta_decay=0.5, seed=seed, bc=bc_config(seed))
    policy: ActorCritic = make_policy(env.observation_space, env.action_space, **policy_options(config.bc))
    with tempfile.TemporaryDirectory(prefix="dagger-rounds-") as round_dir:
        dagger = DAgger(
            env, expert, policy, config, round_dir=round_dir, env_id=ENV_ID,
            evaluate=lambda learner: mean_return(SingleObservationPolicy(learner), env),
        )
        rows = run_learner(dagger)
    return [(int(row["expert_labels"]), row["return"]) for row in rows]


def first_reaching(labels: list[int], normalised: np.ndarray) -> int | None:
    """The first label count whose mean normalised return is ≥ TARGET."""
    hits = np.flatnonzero(normalised.mean(axis=0) >= TARGET)
    return labels[hits[0]] if len(hits) else None


def print_table(name: str, labels: list[int], normalised: np.ndarray, seeds: list[int]) -> None:
    """Markdown table: labels, mean and per-seed normalised return."""
    print(f"\n{name}\n")
    print("| expert labels | mean | " + " | ".join(f"seed {s}" for s in seeds) + " |")
    print("|---:|---:|" + "---:|" * len(seeds))
    for j, count in enumerate(labels):
        print(f"| {count} | {normalised[:, j].mean():.3f} | " + " | ".join(f"{v:.3f}" for v in normalised[:, j]) + " |")


def plot(curves: dict[str, tuple[list[int], np.ndarray]]) -> None:
    """Normalised return against labels: mean line, min–max band over seeds, log x axis."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    figure, axes = plt.subplots(figsize=(6, 4), dpi=80)
    for (name, (labels, normalised)), colour in zip(curves.items(), ("tab:blue", "tab:orange")):
        axes.plot(labels, normalised.mean(axis=0), marker="o", color=colour, label=f"{name} (mean of {len(normalised)} seeds)")
        axes.fill_between(labels, normalised.min(axis=0), normalised.max(axis=0), color=colour, alpha=0.2)
    axes.axhline(TARGET, color="grey", linestyle="--", linewidth=1, label=f"{TARGET} of expert")
    axes.set_xscale("log")
    # Plain numbers at powers-of-two label counts: log-scale minor labels (2×10², 3×10², …) overlap.
    ticks = [200 * 2**k for k in range(8) if 200 * 2**k <= max(max(labels) for labels, _ in curves.values())]
    axes.set_xticks(ticks, [str(t) for t in ticks])
    axes.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    axes.set_xlabel("expert-labelled transitions")
    axes.set_ylabel("normalised return")
    axes.set_title(f"{ENV_ID}: DAgger vs BC (band: min–max over seeds)")
    axes.legend(loc="lower right")
    axes.grid(True, which="both", alpha=0.3)
    figure.tight_layout()
    figure.savefig(PLOT)
    plt.close(figure)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3], help="training seeds (default: 1 2 3)")
    parser.add_argument("--quick", action="store_true", help=f"BC budgets {QUICK_BC_EPISODES} episodes and {QUICK_DAGGER_ROUNDS} DAgger rounds, for a smoke test")
    args = parser.parse_args()
    started = time.perf_counter()
    torch.set_num_threads(1)  # the machine has 2 cores and other benchmarks may share it
    budgets = QUICK_BC_EPISODES if args.quick else BC_EPISODES
    rounds = QUICK_DAGGER_ROUNDS if args.quick else DAGGER_ROUNDS

    env = make_env(ENV_ID)
    expert = scripted_expert(ENV_ID)
    r_expert = mean_return(expert, env)
    r_random = mean_return(random_policy(env, seed=0), env)
    print(f"{ENV_ID}: R_expert = {r_expert:.1f}, R_random = {r_random:.1f} ({EVAL_EPISODES} episodes, reset seeds {EVAL_SEED}…)")

    raw: dict[str, list[Curve]] = {"BC": [], "DAgger": []}
    for seed in args.seeds:
        raw["BC"].append(bc_curve(env, expert, seed, budgets))
        raw["DAgger"].append(dagger_curve(env, expert, seed, rounds))
        print(f"seed {seed} done ({time.perf_counter() - started:.0f} s)", flush=True)

    curves: dict[str, tuple[list[int], np.ndarray]] = {}
    for name, per_seed in raw.items():
        labels = [count for count, _ in per_seed[0]]
        # Pendulum episodes never end early, so every seed spends the same labels at each point.
        assert all([count for count, _ in curve] == labels for curve in per_seed), f"{name}: label counts differ between seeds"
        returns = np.array([[value for _, value in curve] for curve in per_seed])
        curves[name] = (labels, (returns - r_random) / (r_expert - r_random))
        print_table(name, labels, curves[name][1], args.seeds)

    print(f"\nfirst label count at which the mean normalised return is ≥ {TARGET}:")
    for name, (labels, normalised) in curves.items():
        hit = first_reaching(labels, normalised)
        print(f"  {name}: {hit if hit is not None else 'not reached'}")
    plot(curves)
    print(f"\nplot: {PLOT.relative_to(BENCH.parent)}")
    print(f"total runtime: {time.perf_counter() - started:.0f} s")


if __name__ == "__main__":
    main()
