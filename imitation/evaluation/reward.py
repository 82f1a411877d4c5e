"""Is a recovered reward any good? Three lenses at once, beside two controls.

1. **EPIC** (`imitation.evaluation.epic`): the distance between the recovered and the true
   reward once potential shaping and scale are removed; 0 means "the same task". Exact on
   tabular MDPs (uniform D_S, D_A and coverage over every (s, a, s')); on continuous envs it is
   estimated over a coverage batch of the demos' transitions, rollouts of a uniform random
   policy, rollouts of the policies retrained on the recovered reward, and transitions drawn
   uniformly from the space bounds (`coverage_samples`); D_S and D_A are that batch's own states
   and actions. The plain Pearson correlation is reported beside it.
2. **Retraining**: a policy trained from scratch on the recovered reward, judged by the true
   return, normalised (R − R_random)/(R_expert − R_random). Continuous envs: the bundled PPO
   trainer (learned-reward defaults) for K seeds, each policy evaluated deterministically;
   R_expert is the demos' mean return and R_random that of uniform random actions. Tabular
   MDPs: the soft-optimal policy for the reward, whose true return is exact (so one "seed"), and
   the references are the exact returns of the uniform policy and of the soft-optimal policy
   for the true reward (the policy the demos were sampled from).
3. **Controls** go through the same two lenses: a constant reward (what early termination
   alone teaches) and the recovered reward's network with random weights, so the reader sees
   what "good" means on this env.

This module computes the lenses, plots and report from rewards, retrained returns and coverage
samples; the job that retrains the policies and writes the output directory is
`imitation.jobs.evaluate_reward`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from imitation.data.types import Transitions
from imitation.envs.tabular import TabularMDP
from imitation.envs.tabular_planning import soft_optimal_returns
from imitation.evaluation.epic import EpicResult, TransitionBatch, epic_distance_sampled, epic_distance_tabular, torch_reward
from imitation.evaluation.plots import plot_grid_maps, plot_return_distributions, plot_reward_scatter, plot_state_slices
from imitation.evaluation.policy import normalized
from imitation.rewards import RewardNet, all_state_rewards, constant_reward_like, random_reward_like

CONTROLS = ("constant", "random")
CONSTANT_TRUTH = (
    "constant on the coverage batch: EPIC and Pearson are undefined (every reward is equally far from it); "
    "only the retrained returns judge the reward"
)
TrueReward = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]


@dataclass(kw_only=True)
class SampledEvaluation:
    """How sampled EPIC is estimated: transitions drawn uniformly from the space bounds added to
    the coverage batch, samples per conditional mean, and the seed of both."""

    coverage_uniform: int = 2048
    mean_samples: int = 512
    seed: int = 0


@dataclass
class Retraining:
    """Policies retrained from scratch on each reward: PPO's steps and seeds, and per reward
    name the retrained policies' true returns and their run directories."""

    steps: int
    seeds: list[int]
    returns: dict[str, list[float]]
    runs: dict[str, list[str]]
    estimated_seconds: float | None = None  # what the job expected the retraining to take


def with_controls(model: RewardNet, *, seed: int) -> dict[str, RewardNet]:
    """The recovered reward beside the two controls: a constant reward, and its network with
    random weights (drawn with `seed`)."""
    return {"learned": model, "constant": constant_reward_like(model), "random": random_reward_like(model, seed=seed)}


def _state_rewards(model: RewardNet, n_states: int) -> np.ndarray:
    return all_state_rewards(model, n_states).detach().double().numpy()


# ------------------------------------------------------------------------------------------------
# Tabular MDPs: everything exact


def evaluate_tabular_reward(
    model: RewardNet, mdp: TabularMDP, env_id: str, *, discount: float, seed: int, out: Path
) -> dict[str, Any]:
    """Every lens exact, for the recovered reward and the controls (the random network drawn
    with `seed`); plots to folder `out`."""
    rewards = {name: _state_rewards(reward, mdp.n_states) for name, reward in with_controls(model, seed=seed).items()}
    lenses = {}
    for name, reward in rewards.items():
        epic = epic_distance_tabular(reward, mdp.reward, mdp.n_states, mdp.n_actions, discount)
        returns = soft_optimal_returns(mdp, reward, discount=discount)
        lenses[name] = {
            "epic": epic.epic,
            "pearson": epic.pearson,
            "mean_return": returns["learned_policy_return"],
            "normalized": returns["normalized_return"],
        }
    references = {
        "expert_return": returns["expert_return"],
        "random_return": returns["random_return"],
        "source": "exact returns of the soft-optimal and the uniform policy",
    }
    plots = {"reward_scatter": "reward_scatter.png"}
    plot_reward_scatter(
        out / plots["reward_scatter"],
        mdp.reward,
        {name: reward for name, reward in rewards.items()},
        xlabel="true reward r(s)",
        title=f"{env_id}: rewards of every state",
    )
    if mdp.grid_shape is not None:
        plots["reward_maps"] = "reward_maps.png"
        plot_grid_maps(
            out / plots["reward_maps"], {"true": mdp.reward, **rewards}, grid_shape=mdp.grid_shape, title=f"{env_id}: rewards"
        )
    return _results(
        lenses,
        references,
        retrain_steps=0,
        seeds=[None],
        coverage={"kind": "exact", "transitions": mdp.n_states**2 * mdp.n_actions, "discount": discount},
        plots=plots,
    )


# ------------------------------------------------------------------------------------------------
# Continuous envs: sampled EPIC and retrained returns


def evaluate_sampled_reward(
    rewards: dict[str, RewardNet],
    truth: TrueReward | None,
    coverage: TransitionBatch,
    *,
    env: gym.Env,
    env_id: str,
    discount: float,
    demos: Transitions,
    rollout_transitions: int,
    retraining: Retraining,
    references: dict[str, Any],
    config: SampledEvaluation,
    out: Path,
) -> dict[str, Any]:
    """The lenses of `rewards` (the recovered one and the controls, `with_controls`): sampled
    EPIC over `coverage` (the demos, `rollout_transitions` steps of rollouts and uniform samples)
    against `truth` when the env's true reward is known, and the true returns of the policies
    retrained on each; plots to folder `out`."""
    random_return, expert_return = references["random_return"], references["expert_return"]
    true_values = truth(*coverage) if truth is not None else None
    # A true reward that is the same for every transition (MountainCar's -1 per step) ranks nothing:
    # every reward is equally far from it, so EPIC and Pearson are undefined, and only retraining judges.
    constant_truth = true_values is not None and bool(
        np.ptp(true_values) <= 1e-12 * max(1.0, float(np.abs(true_values).max()))
    )
    lenses: dict[str, dict[str, Any]] = {}
    for name, reward in rewards.items():
        epic: EpicResult | None = None
        if truth is not None and not constant_truth:
            epic = epic_distance_sampled(
                torch_reward(reward),
                truth,
                coverage,
                coverage.observations,
                coverage.actions,
                discount,
                seed=config.seed,
                n_mean_samples=config.mean_samples,
            )
        returns = retraining.returns.get(name, [])
        lenses[name] = {
            "epic": epic.epic if epic else None,
            "pearson": epic.pearson if epic else None,
            "mean_return": float(np.mean(returns)) if returns else None,
            "normalized": normalized(float(np.mean(returns)), random_return, expert_return) if returns else None,
            "seed_returns": returns,
            "seed_normalized": [normalized(value, random_return, expert_return) for value in returns],
            "seed_runs": retraining.runs.get(name, []),
        }

    plots: dict[str, str] = {}
    if true_values is not None:
        plots["reward_scatter"] = "reward_scatter.png"
        plot_reward_scatter(
            out / plots["reward_scatter"],
            true_values,
            {name: torch_reward(reward)(*coverage) for name, reward in rewards.items()},
            xlabel="true reward R(s, a, s')",
            title=f"{env_id}: rewards on the EPIC coverage batch",
        )
    if (
        isinstance(env.observation_space, gym.spaces.Box)
        and env.observation_space.shape
        and np.prod(env.observation_space.shape) >= 2
    ):
        plots["state_slices"] = "state_slices.png"
        # Arrays, not dicts: the observations are Box here, and a reward model takes no Dict actions.
        assert isinstance(demos.observations, np.ndarray) and isinstance(demos.actions, np.ndarray)
        slices = {"recovered": torch_reward(rewards["learned"])} | ({"true": truth} if truth is not None else {})
        plot_state_slices(
            out / plots["state_slices"],
            demos.observations,
            demos.actions,
            slices,
            env.observation_space,
            title=f"{env_id}: reward over a 2-D slice of the state space",
        )
    steps = retraining.steps
    if steps > 0:
        plots["retrain_returns"] = "retrain_returns.png"
        plot_return_distributions(
            out / plots["retrain_returns"],
            {name: lenses[name]["seed_returns"] for name in rewards},
            {"demos": expert_return, "random policy": random_return},
            title=f"{env_id}: true return after retraining PPO ({steps:,} steps)",
        )
    return _results(
        lenses,
        references,
        retrain_steps=steps,
        seeds=retraining.seeds if steps > 0 else [],
        coverage={
            "kind": "sampled",
            "transitions": len(coverage.observations),
            "demo_transitions": len(demos),
            "rollout_transitions": rollout_transitions,
            "uniform_transitions": config.coverage_uniform,
            "mean_samples": config.mean_samples,
            "discount": discount,
            "true_reward": (
                "unknown for this env: no EPIC" if truth is None else CONSTANT_TRUTH if constant_truth else "known"
            ),
        },
        plots=plots,
        estimated_seconds=retraining.estimated_seconds,
    )


# ------------------------------------------------------------------------------------------------
# Results and report


def _results(
    lenses: dict[str, dict[str, Any]],
    references: dict[str, Any],
    *,
    retrain_steps: int,
    seeds: list[Any],
    coverage: dict[str, Any],
    plots: dict[str, str],
    estimated_seconds: float | None = None,
) -> dict[str, Any]:
    learned = lenses["learned"]
    return {
        "epic": learned["epic"],
        "pearson": learned["pearson"],
        "retrain": {
            "mean_return": learned["mean_return"],
            "normalized": learned["normalized"],
            "seeds": seeds,
            "steps": retrain_steps,
            "seed_returns": learned.get("seed_returns", []),
            "seed_normalized": learned.get("seed_normalized", []),
            "seed_runs": learned.get("seed_runs", []),
            "estimated_seconds": estimated_seconds,
        },
        "controls": {name: lenses[name] for name in CONTROLS},
        "references": references,
        "coverage": coverage,
        "plots": plots,
    }


def _number(value: float | None, digits: int = 3) -> str:
    return "n/a" if value is None else f"{value:.{digits}f}"


def reward_report(results: dict[str, Any], *, heading: str = "#", image_prefix: str = "") -> str:
    """The evaluation as Markdown: one table of the three lenses, then the plots."""
    retrain, controls = results["retrain"], results["controls"]
    rows = [("recovered reward", results["epic"], results["pearson"], retrain["mean_return"], retrain["normalized"])]
    rows += [
        (f"control: {name} reward", c["epic"], c["pearson"], c["mean_return"], c["normalized"]) for name, c in controls.items()
    ]
    how = (
        "exact soft-optimal policy for each reward (tabular MDP)"
        if results["coverage"]["kind"] == "exact"
        else f"PPO from scratch, {retrain['steps']:,} steps, seeds {retrain['seeds']}, deterministic evaluation"
    )
    references = results["references"]
    lines = [
        f"{heading} Reward evaluation: `{results['run']}` on {results['env_id']}",
        "",
        f"Retraining: {how}. Normalised return = (R − R_random)/(R_expert − R_random) with R_expert = "
        f"{references['expert_return']:.2f} and R_random = {references['random_return']:.2f} ({references['source']}). EPIC: "
        "0 = the same task as the true reward, √½ ≈ 0.707 = unrelated, 1 = the opposite; coverage: "
        f"{results['coverage']['kind']}, {results['coverage']['transitions']:,} transitions.",
        "",
        "| reward | EPIC ↓ | Pearson ↑ | true return | normalised ↑ |",
        "|---|---:|---:|---:|---:|",
        *(
            f"| {name} | {_number(epic)} | {_number(pearson)} | {_number(value, 2)} | {_number(norm)} |"
            for name, epic, pearson, value, norm in rows
        ),
        "",
    ]
    if results["coverage"].get("true_reward") == CONSTANT_TRUTH:
        lines += [f"The true reward is {CONSTANT_TRUTH}.", ""]
    if retrain.get("seed_returns"):
        lines += [
            "Recovered reward, per seed: "
            + ", ".join(
                f"seed {s}: {r:.1f} ({n:.2f})"
                for s, r, n in zip(retrain["seeds"], retrain["seed_returns"], retrain["seed_normalized"])
            ),
            "",
        ]
    lines += [f"![{name}]({image_prefix}{file})" for name, file in results["plots"].items()]
    return "\n".join(lines) + "\n"
