"""Claim (e) of the notes (§5.2–5.3): apprenticeship learning and maximum-entropy IRL, on the same demos.

Both recover a reward linear in the same state features from the same demonstrations, and both
aim at matching the expert's feature expectations μ_E = E[Σ_t γ^t φ(s_t)]. Apprenticeship learning
(Abbeel & Ng's projection method) finds a *mixture* of policies whose μ̄ matches μ_E, and its w
need not explain the demos; MaxEnt IRL (here the maximum *causal* entropy variant, which is exact
for stochastic dynamics) picks the one reward under which the demos are most likely, and its
soft-optimal policy matches μ_E by construction. The notes' comparison: feature matching alone
is ambiguous (many w, a mixture rather than a policy); the maximum-entropy principle resolves it.

On the bundled 8×8 gridworld demos (deterministic and slippery), with the toolkit's own jobs and
every measurement exact (known dynamics):

- the feature-expectation gap ‖μ − μ_E‖₂ / ‖μ_E‖₂: of apprenticeship learning's mixture μ̄, and of
  MCE IRL's soft-optimal policy for its reward;
- EPIC distance of each recovered reward to the true one (`eval reward`; 0 is equivalent, 1 unrelated);
- the retrained return: the true return of the policy soft-optimal for the recovered reward,
  normalised between the uniform random policy (0) and the expert (1) (`eval reward`), and of the
  (hard) optimal policy for it. The soft-optimal policy depends on the reward's scale, which
  MaxEnt IRL learns and apprenticeship learning does not (its w has ‖w‖₂ = 1): the optimal
  policy's return is the scale-free comparison;
- wall time of learning.

Verdict: the claim "both match the expert's features, and MaxEnt IRL's reward is the one that
transfers" holds here when both gaps are ≤ 0.05 and MCE's EPIC distance is no larger than
apprenticeship learning's.

Usage: python bench/claim_apprenticeship.py
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from contextlib import closing
from pathlib import Path

import numpy as np

BENCH = Path(__file__).resolve().parent
REPO = BENCH.parent
sys.path.insert(0, str(REPO))  # run from a checkout without installing the package

from imitation.algorithms.apprenticeship import ApprenticeshipConfig, optimal_policy  # noqa: E402
from imitation.algorithms.maxent_irl import MaxEntIRLConfig, demo_visitation  # noqa: E402
from imitation.algorithms.ppo import PPOConfig  # noqa: E402
from imitation.data.dataset import DemoDataset  # noqa: E402
from imitation.envs.make import make_env  # noqa: E402
from imitation.envs.tabular import TabularMDP  # noqa: E402
from imitation.envs.tabular_planning import (  # noqa: E402
    Dynamics,
    expected_return,
    soft_optimal_policy,
    soft_optimal_returns,
    visits_by_time,
)
from imitation.jobs.apprenticeship import apprenticeship_job  # noqa: E402
from imitation.jobs.evaluate_reward import RewardEvaluationConfig, evaluate_reward  # noqa: E402
from imitation.jobs.irl import tabular_irl_job  # noqa: E402
from imitation.rewards import all_state_rewards, load_reward  # noqa: E402

ENVS = {
    "imitation/GridWorld8x8-v0": REPO / "datasets" / "GridWorld8x8-v0.mcap",
    "imitation/GridWorld8x8Slippery-v0": REPO / "datasets" / "GridWorld8x8Slippery-v0.mcap",
}


def tabular_mdp(env_id: str) -> TabularMDP:
    with closing(make_env(env_id)) as env:
        return env.unwrapped.mdp


def state_rewards(run: Path, mdp: TabularMDP) -> np.ndarray:
    return all_state_rewards(load_reward(run), mdp.n_states).detach().numpy().astype(np.float64)


def optimal_normalized_return(env_id: str, run: Path) -> float:
    """The true return of the (hard) optimal policy for run's reward, normalised like `eval reward`'s."""
    mdp = tabular_mdp(env_id)
    dynamics = Dynamics.of(mdp.transition)
    learned = expected_return(
        dynamics, mdp, optimal_policy(dynamics, state_rewards(run, mdp), horizon=mdp.horizon, discount=1.0)
    )
    references = soft_optimal_returns(mdp, mdp.reward, discount=1.0)
    return (learned - references["random_return"]) / (references["expert_return"] - references["random_return"])


def soft_optimal_feature_gap(env_id: str, run: Path, demos: Path) -> float:
    """‖μ(π_soft) − μ_E‖ / ‖μ_E‖ for the policy soft-optimal for run's reward (γ = 1)."""
    mdp = tabular_mdp(env_id)
    policy = soft_optimal_policy(mdp, state_rewards(run, mdp), discount=1.0)
    mu = visits_by_time(Dynamics.of(mdp.transition), mdp.initial, policy).sum(axis=0) @ mdp.features
    episodes = DemoDataset([str(demos)]).read_episodes()
    mu_expert = demo_visitation(episodes, n_states=mdp.n_states, horizon=mdp.horizon, discount=1.0) @ mdp.features
    return float(np.linalg.norm(mu - mu_expert) / np.linalg.norm(mu_expert))


def main() -> None:
    argparse.ArgumentParser(description=__doc__.split("\n\n")[0]).parse_args()
    started = time.perf_counter()
    verdicts = {}
    with tempfile.TemporaryDirectory(prefix="claim-apprenticeship-") as folder:
        work = Path(folder)
        for env_id, demos in ENVS.items():
            name = env_id.split("/")[1]
            rows = {}
            apprenticeship = apprenticeship_job(
                [str(demos)], env_id, ApprenticeshipConfig(), PPOConfig(env_id=env_id), work / f"{name}-app", progress=False
            )
            mce = tabular_irl_job([str(demos)], env_id, MaxEntIRLConfig(method="mce"), work / f"{name}-mce", progress=False)
            gaps = {
                "apprenticeship": apprenticeship["relative_feature_distance"],
                "mce": soft_optimal_feature_gap(env_id, work / f"{name}-mce", demos),
            }
            for method, result in (("apprenticeship", apprenticeship), ("mce", mce)):
                evaluation = evaluate_reward(
                    result["run"], env_id, RewardEvaluationConfig(), work / f"{name}-{method}-eval", progress=False
                )
                rows[method] = {
                    "gap": gaps[method],
                    "epic": evaluation["epic"],
                    "normalized": evaluation["retrain"]["normalized"],
                    "optimal": optimal_normalized_return(env_id, Path(result["run"])),
                    "seconds": result["seconds"],
                }
            print(f"\n### {env_id} (demos: {demos.relative_to(REPO)})\n")
            print(
                "| method | ‖μ − μ_E‖/‖μ_E‖ | EPIC to the true reward | soft-optimal policy's return, normalised | "
                "optimal policy's return, normalised | learning time (s) |"
            )
            print("|---|---:|---:|---:|---:|---:|")
            for method, row in rows.items():
                label = "apprenticeship (mixture μ̄)" if method == "apprenticeship" else "MCE IRL (soft-optimal policy)"
                print(
                    f"| {label} | {row['gap']:.4f} | {row['epic']:.3f} | {row['normalized']:.3f} | {row['optimal']:.3f} | {row['seconds']:.2f} |"
                )
            verdicts[env_id] = (
                rows["apprenticeship"]["gap"] <= 0.05
                and rows["mce"]["gap"] <= 0.05
                and rows["mce"]["epic"] <= rows["apprenticeship"]["epic"]
            )
    print()
    for env_id, holds in verdicts.items():
        print(
            f"verdict (e), {env_id}: both match μ_E and MaxEnt IRL's reward is the closer one: "
            f"{'holds' if holds else 'does not hold here'}"
        )
    print(f"total runtime: {time.perf_counter() - started:.0f} s")


if __name__ == "__main__":
    main()
