"""Claim (c) of the notes (§5.1): BC's error compounds over the horizon, ∝ T², and DAgger's does not, ∝ T.

Ross & Bagnell's bound: a policy whose per-step mistake rate is ε *on the expert's states*
costs at most J* + T²ε over horizon T (BC), while one trained on its *own* state distribution
(DAgger) costs at most J* + Tε (+ lower-order terms). The reason is that a mistake takes BC to a
state the expert never showed it, where it keeps making mistakes.

Task: a lane. The state is the lateral offset d ∈ {-12, …, 12} (a tabular MDP, one-hot
observations, deterministic moves), the actions steer left, straight or right by one, and off
the centre (d ≠ 0) costs 1 per step. The expert drives straight down the centre, so its
demonstrations show d = 0 only. A learner errs with probability ε = 0.02 per step (its action is
replaced by a random one: the per-step mistake rate ε the bound assumes of an imperfect fit);
the expert never does. A learner that has drifted off the centre meets states with no label.

- BC: the toolkit's BC (`BehaviouralCloning`) on `LABELS` expert-labelled steps (clean expert
  episodes of 100 steps).
- DAgger: the toolkit's `DAgger` with the same number of expert labels (one 100-step episode a
  round, β_i = 0.5^(i-1)); in the steps it drives, its learner errs with probability ε too, so
  its rounds visit the states its own mistakes lead to, and the expert labels them.
- Both fit the same one-hot MLP; each is then read out as a table π(d), and its expected cost
  over horizon T, with the ε mistakes, is computed *exactly* by propagating the state
  distribution through the known dynamics: J_T(π) = Σ_{t<T} Σ_d P(d_t = d | π, ε) c(d). The
  expert's J_T is 0, so the cost gap is J_T(π), with no Monte Carlo noise.
- Horizons run from 5 to 160 steps, below 1/ε, where the T² regime of the bound lives (a
  learner that has drifted off pays at most 1 a step, so every gap is linear for T ≫ 1/ε).
- The exponent is the slope of log gap against log T (least squares). The claim holds here
  when BC's exponent is near 2 (> 1.6) and DAgger's near 1 (< 1.4).

Usage: python bench/claim_compounding.py [--seeds 0 1 2 3 4] [--plot PATH]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

BENCH = Path(__file__).resolve().parent
sys.path.insert(0, str(BENCH.parent))  # run from a checkout without installing the package

from imitation.algorithms.bc import BCConfig, BehaviouralCloning, fit, policy_options  # noqa: E402
from imitation.algorithms.dagger import DAgger, DAggerConfig, collect_round  # noqa: E402
from imitation.data.loader import transitions_to_torch  # noqa: E402
from imitation.data.types import episodes_to_transitions  # noqa: E402
from imitation.envs.tabular import TabularEnv, TabularMDP  # noqa: E402
from imitation.jobs.loop import run as run_learner  # noqa: E402
from imitation.policies import ActorCritic, make_policy  # noqa: E402

HALF_WIDTH = 12
MISTAKE_RATE = 0.02  # ε
EPISODE_STEPS = 100
LABELS = 1000
HORIZONS = (5, 10, 20, 40, 80, 160)
PLOT = BENCH / "claim_compounding.png"

STATES = 2 * HALF_WIDTH + 1
OFFSETS = np.arange(-HALF_WIDTH, HALF_WIDTH + 1)
COST = (OFFSETS != 0).astype(float)
EXPERT_TABLE = np.where(OFFSETS < 0, 2, np.where(OFFSETS > 0, 0, 1))  # steer right, left, straight


def lane_mdp() -> TabularMDP:
    transition = np.zeros((STATES, 3, STATES))
    for state, offset in enumerate(OFFSETS):
        for action in range(3):
            transition[state, action, np.clip(offset + action - 1, -HALF_WIDTH, HALF_WIDTH) + HALF_WIDTH] = 1.0
    initial = np.zeros(STATES)
    initial[HALF_WIDTH] = 1.0
    return TabularMDP(transition=transition, initial=initial, features=np.eye(STATES), reward=-COST, horizon=EPISODE_STEPS)


def expert(observation: int) -> int:
    return int(EXPERT_TABLE[int(observation)])


def expected_cost(table: np.ndarray, mdp: TabularMDP, horizons: tuple[int, ...], mistake_rate: float) -> np.ndarray:
    """J_T(π) for each T in `horizons`, propagating P(d_t) through (1 - ε) P[d, π(d), ·] + ε mean_a P[d, a, ·]."""
    step = (1 - mistake_rate) * mdp.transition[np.arange(STATES), table] + mistake_rate * mdp.transition.mean(axis=1)
    distribution, total, costs = mdp.initial.copy(), 0.0, {}
    for t in range(1, max(horizons) + 1):
        total += distribution @ COST
        distribution = distribution @ step
        costs[t] = total
    return np.array([costs[T] for T in horizons])


def as_table(policy: ActorCritic) -> np.ndarray:
    return np.asarray(policy.predict(np.arange(STATES)), dtype=np.int64).reshape(-1)


def bc_config(seed: int) -> BCConfig:
    return BCConfig(
        epochs=50,
        patience=10,
        batch_size=64,
        hidden_sizes=[64, 64],
        activation="tanh",
        validation_fraction=0.0,
        seed=seed,
        device="cpu",
        threads=1,
    )


def train_bc(env: TabularEnv, seed: int) -> np.ndarray:
    torch.manual_seed(seed)
    episodes = collect_round(
        env,
        None,
        expert,
        beta=1.0,
        episodes=LABELS // EPISODE_STEPS,
        seed=seed * 1_000,
        rng=np.random.default_rng(seed),
        metadata={"source": "expert"},
    )
    config = bc_config(seed)
    policy = make_policy(env.observation_space, env.action_space, **policy_options(config, LABELS))
    learner = BehaviouralCloning(
        policy, transitions_to_torch(episodes_to_transitions(episodes, next_observations=False)), None, config
    )
    fit(learner)
    return as_table(learner.policy)


class Erring:
    """A learner that errs: with probability ε a random action instead of its own."""

    def __init__(self, learner: Callable[[int], int], rng: np.random.Generator) -> None:
        self.learner, self.rng = learner, rng

    def __call__(self, observation: int) -> int:
        return int(self.rng.integers(3)) if self.rng.random() < MISTAKE_RATE else int(self.learner(observation))


class ErringDAgger(DAgger):
    """DAgger whose learner errs in the steps it drives (the expert, which labels, does not)."""

    def step(self) -> dict[str, float]:
        row = super().step()
        assert self.learner is not None
        self.learner = Erring(self.learner, self.rng)
        return row


def train_dagger(env: TabularEnv, seed: int) -> np.ndarray:
    torch.manual_seed(seed)
    config = DAggerConfig(
        rounds=LABELS // EPISODE_STEPS,
        episodes_per_round=1,
        beta_schedule="exponential",
        beta_decay=0.5,
        seed=seed,
        bc=bc_config(seed),
    )
    policy = make_policy(env.observation_space, env.action_space, **policy_options(config.bc, LABELS))
    with tempfile.TemporaryDirectory(prefix="claim-compounding-") as round_dir:
        dagger = ErringDAgger(env, expert, policy, config, round_dir=round_dir, env_id="lane", evaluate=lambda learner: 0.0)
        run_learner(dagger)
    return as_table(dagger.policy)


def exponent(gaps: np.ndarray) -> float | None:
    """Slope of log gap on log T over the horizons with a positive gap (None with fewer than 3)."""
    positive = gaps > 1e-9
    if positive.sum() < 3:
        return None
    return float(np.polyfit(np.log(np.array(HORIZONS)[positive]), np.log(gaps[positive]), 1)[0])


def plot(gaps: dict[str, np.ndarray], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(figsize=(6, 4), dpi=80)
    for (name, per_seed), colour in zip(gaps.items(), ("tab:blue", "tab:orange")):
        mean = per_seed.mean(axis=0)
        axes.plot(HORIZONS, np.maximum(mean, 1e-4), marker="o", color=colour, label=f"{name} (mean of {len(per_seed)} seeds)")
    # Reference slopes drawn through each method's first point.
    horizons = np.array(HORIZONS, dtype=float)
    bc_start, dagger_start = gaps["BC"].mean(axis=0)[0], gaps["DAgger"].mean(axis=0)[0]
    axes.plot(horizons, bc_start * (horizons / horizons[0]) ** 2, color="grey", linestyle="--", linewidth=1, label="∝ T²")
    axes.plot(horizons, dagger_start * horizons / horizons[0], color="grey", linestyle=":", linewidth=1, label="∝ T")
    axes.set_xscale("log")
    axes.set_yscale("log")
    axes.set_xlabel("horizon T")
    axes.set_ylabel("cost gap J_T(π) − J_T(π*)")
    axes.set_title(f"Compounding error on the lane (ε = {MISTAKE_RATE}, {LABELS} expert labels each)")
    axes.legend(loc="upper left")
    axes.grid(True, which="both", alpha=0.3)
    figure.tight_layout()
    figure.savefig(path)
    plt.close(figure)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="training seeds (default: 0 1 2)")
    parser.add_argument(
        "--plot", type=Path, default=PLOT, help=f"where the plot goes (default: {PLOT.relative_to(BENCH.parent)})"
    )
    args = parser.parse_args()
    started = time.perf_counter()
    torch.set_num_threads(1)
    mdp = lane_mdp()
    env = TabularEnv(mdp)
    expert_cost = expected_cost(EXPERT_TABLE, mdp, HORIZONS, 0.0)
    gaps: dict[str, list[np.ndarray]] = {"BC": [], "DAgger": []}
    for seed in args.seeds:
        gaps["BC"].append(expected_cost(train_bc(env, seed), mdp, HORIZONS, MISTAKE_RATE) - expert_cost)
        gaps["DAgger"].append(expected_cost(train_dagger(env, seed), mdp, HORIZONS, MISTAKE_RATE) - expert_cost)
        print(f"seed {seed} done ({time.perf_counter() - started:.0f} s)", flush=True)
    arrays = {name: np.array(per_seed) for name, per_seed in gaps.items()}

    print("\nexpert cost J_T(π*): " + ", ".join(f"T={T}: {cost:.2f}" for T, cost in zip(HORIZONS, expert_cost)))
    print("\n| method | " + " | ".join(f"T={T}" for T in HORIZONS) + " | exponent of the mean |")
    print("|---|" + "---:|" * (len(HORIZONS) + 1))
    exponents = {}
    for name, per_seed in arrays.items():
        exponents[name] = exponent(per_seed.mean(axis=0))
        shown = "no positive gap" if exponents[name] is None else f"{exponents[name]:.2f}"
        print(f"| {name} | " + " | ".join(f"{gap:.3g}" for gap in per_seed.mean(axis=0)) + f" | {shown} |")
    for name, per_seed in arrays.items():
        per_seed_exponents = [exponent(row) for row in per_seed]
        print(f"{name} per-seed exponents: " + ", ".join("—" if e is None else f"{e:.2f}" for e in per_seed_exponents))
    bc, dagger = exponents["BC"], exponents["DAgger"]
    holds = bc is not None and bc > 1.6 and dagger is not None and dagger < 1.4
    print(
        f"\nverdict (c): {'holds' if holds else 'does not hold here'}: BC's cost gap grows as T^{bc if bc is None else round(bc, 2)}, "
        f"DAgger's as {'nothing (zero gap)' if dagger is None else f'T^{dagger:.2f}'}"
    )
    plot(arrays, args.plot)
    print(f"plot: {args.plot}")
    print(f"total runtime: {time.perf_counter() - started:.0f} s")


if __name__ == "__main__":
    main()
