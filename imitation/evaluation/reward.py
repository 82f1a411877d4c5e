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

Everything lands in one output directory: metrics.json, plots, report.md (and report.html) and the retrained runs.
"""

from __future__ import annotations

import os
from concurrent.futures import ProcessPoolExecutor
from contextlib import closing
from dataclasses import dataclass
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from tqdm import tqdm

from imitation.algorithms.maxent_irl import all_state_rewards
from imitation.data.loader import load_transitions
from imitation.data.spaces import check_spaces_fit
from imitation.data.store import DemoDataset
from imitation.envs.make import make_env
from imitation.envs.rollout import collect_transitions
from imitation.envs.tabular import TabularEnv
from imitation.envs.true_rewards import true_reward
from imitation.errors import ImitationError
from imitation.evaluation.epic import (
    EpicResult,
    TransitionBatch,
    coverage_samples,
    epic_distance_sampled,
    epic_distance_tabular,
    torch_reward,
)
from imitation.evaluation.policy import evaluate_policy
from imitation.evaluation.report import write_report
from imitation.evaluation.plots import plot_grid_maps, plot_return_distributions, plot_reward_scatter, plot_state_slices
from imitation.experts.load import load_expert
from imitation.rewards import RewardNet, constant_reward_like, load_reward, random_reward_like, save_reward_run
from imitation.runs import RunWriter, read_run

EVAL_SEED = 10_000  # the same evaluation seeds as every training job's final evaluation
REFERENCE_EPISODES = 10
ROLLOUT_EPISODES = 4  # per policy, for the coverage batch
# PPO steps that retrain a policy on a learned reward by default (measured, bench/RESULTS.md:
# Pendulum's retraining on a sound reward reached 1.01 at 600k where 300k gave 0.58).
DEFAULT_RETRAIN_STEPS = {"imitation/CartPoleFixedHorizon-v0": 300_000, "Pendulum-v1": 600_000}
FALLBACK_RETRAIN_STEPS = 200_000
CONTROLS = ("constant", "random")


@dataclass(kw_only=True)
class RewardEvaluationConfig:
    retrain_steps: int | None = None  # None: DEFAULT_RETRAIN_STEPS for the env; 0: no retraining
    seeds: int = 3
    coverage_uniform: int = 2048
    mean_samples: int = 512
    seed: int = 0
    jobs: int = 2  # PPO trainings run side by side, one CPU thread each
    demos: list[str] | None = None  # None: the demos the reward was learned from

    def validate(self) -> None:
        if self.seeds < 1:
            raise ImitationError(f"--seeds must be at least 1, got {self.seeds}")
        if self.retrain_steps is not None and self.retrain_steps < 0:
            raise ImitationError(f"--retrain-steps must be non-negative, got {self.retrain_steps}")
        if self.jobs < 1:
            raise ImitationError(f"--jobs must be at least 1, got {self.jobs}")


def normalized(value: float, random: float, expert: float) -> float:
    """(R − R_random)/(R_expert − R_random): 0 for the random policy, 1 for the expert."""
    return (value - random) / (expert - random)


def evaluate_reward(run: str | os.PathLike, env_id: str, config: RewardEvaluationConfig, out: str | os.PathLike, *, progress: bool = True) -> dict[str, Any]:
    """Evaluate the reward model of run directory `run` on `env_id`; write the results
    (metrics.json), plots and report.md to directory `out` (replaced only when complete)."""
    config.validate()
    model = load_reward(run)
    run_config, _ = read_run(run)
    with closing(make_env(env_id)) as env:
        check_spaces_fit("reward model's", model.observation_space, model.action_space, env, where=f"{run}")
        with RunWriter(out, config={"kind": "reward-evaluation", "run": str(run), "env_id": env_id, "evaluation": vars(config).copy()}, tensorboard=False) as writer:
            if isinstance(env.unwrapped, TabularEnv):
                results = _evaluate_tabular(model, env, env_id, run_config, config, writer.partial)
            else:
                results = _evaluate_continuous(model, env, env_id, run, run_config, config, writer.partial, progress=progress)
            results = {"run": str(run), "env_id": env_id, **results}
            write_report(writer.partial / "report.md", reward_report(results), title=f"Reward evaluation: {run} on {env_id}")
            writer.finish(results)
    return {"out": str(writer.path), **results}


# ------------------------------------------------------------------------------------------------
# Tabular MDPs: everything exact


def _evaluate_tabular(model: RewardNet, env: gym.Env, env_id: str, run_config: dict[str, Any], config: RewardEvaluationConfig, out: Path) -> dict[str, Any]:
    from imitation.training import tabular_policy_returns

    mdp = env.unwrapped.mdp
    discount = float(run_config.get("irl", {}).get("discount", 1.0))
    rewards = {
        "learned": all_state_rewards(model, mdp.n_states).detach().double().numpy(),
        "constant": all_state_rewards(constant_reward_like(model), mdp.n_states).detach().double().numpy(),
        "random": all_state_rewards(random_reward_like(model, seed=config.seed), mdp.n_states).detach().double().numpy(),
    }
    lenses = {}
    for name, reward in rewards.items():
        epic = epic_distance_tabular(reward, mdp.reward, mdp.n_states, mdp.n_actions, discount)
        returns = tabular_policy_returns(mdp, reward, discount=discount)
        lenses[name] = {"epic": epic.epic, "pearson": epic.pearson, "mean_return": returns["learned_policy_return"], "normalized": returns["normalized_return"]}
    references = {"expert_return": returns["expert_return"], "random_return": returns["random_return"], "source": "exact returns of the soft-optimal and the uniform policy"}
    plots = {"reward_scatter": "reward_scatter.png"}
    plot_reward_scatter(out / plots["reward_scatter"], mdp.reward, {name: reward for name, reward in rewards.items()}, xlabel="true reward r(s)", title=f"{env_id}: rewards of every state")
    if mdp.grid_shape is not None:
        plots["reward_maps"] = "reward_maps.png"
        plot_grid_maps(out / plots["reward_maps"], {"true": mdp.reward, **rewards}, grid_shape=mdp.grid_shape, title=f"{env_id}: rewards")
    return _results(lenses, references, retrain_steps=0, seeds=[None], coverage={"kind": "exact", "transitions": mdp.n_states**2 * mdp.n_actions, "discount": discount}, plots=plots)


# ------------------------------------------------------------------------------------------------
# Continuous envs: PPO retraining and sampled EPIC


def _evaluate_continuous(
    model: RewardNet, env: gym.Env, env_id: str, run: str | os.PathLike, run_config: dict[str, Any], config: RewardEvaluationConfig, out: Path, *, progress: bool
) -> dict[str, Any]:
    from imitation.algorithms.ppo import PPOConfig, learned_reward_ppo_defaults

    demo_paths = config.demos if config.demos is not None else run_config.get("demos") or []
    if not demo_paths:
        raise ImitationError(f"{run}: its config names no demos; pass --demos F.mcap (the expert reference and EPIC's coverage)")
    dataset = DemoDataset(demo_paths)
    check_spaces_fit("demos'", dataset.observation_space, dataset.action_space, env, where=str(demo_paths[0]))
    demos = load_transitions(dataset, next_observations=True)
    expert_return = float(np.mean([facts.episode_return for facts in dataset.episodes]))
    random_policy = load_expert("random", env, seed=config.seed)
    random_return = evaluate_policy(random_policy, env, episodes=REFERENCE_EPISODES, seed=EVAL_SEED)["mean_return"]
    references = {"expert_return": expert_return, "random_return": random_return, "source": f"demos' mean return ({len(dataset)} episodes); uniform random actions ({REFERENCE_EPISODES} episodes)"}

    rewards = {"learned": model, "constant": constant_reward_like(model), "random": random_reward_like(model, seed=config.seed)}
    reward_runs = {"learned": Path(run)}
    for name in CONTROLS:
        reward_runs[name] = save_reward_run(rewards[name], out / "controls" / name, env_id=env_id, source=f"eval reward control: {name} reward")
    ppo_settings = learned_reward_ppo_defaults(env_id, env.action_space)
    steps = DEFAULT_RETRAIN_STEPS.get(env_id, FALLBACK_RETRAIN_STEPS) if config.retrain_steps is None else config.retrain_steps
    seeds = list(range(config.seed, config.seed + config.seeds))
    retrained: dict[str, list[dict[str, Any]]] = {name: [] for name in rewards}
    if steps > 0:
        jobs = [
            (name, seed, PPOConfig(env_id=env_id, total_steps=steps, seed=seed, reward_run=str(reward_runs[name]), device="cpu", **ppo_settings), out / "retrain" / f"{name}-seed{seed}")
            for name in rewards for seed in seeds
        ]
        for name, result in _run_ppo_jobs(jobs, workers=config.jobs, progress=progress):
            retrained[name].append(result)

    policy_rollouts = [_policy_transitions(Path(result["run"]), env, seed=EVAL_SEED) for result in retrained["learned"]]
    random_rollouts = collect_transitions(env, random_policy, episodes=ROLLOUT_EPISODES, seed=EVAL_SEED)
    rollouts = TransitionBatch(*(np.concatenate([part[i] for part in [random_rollouts, *policy_rollouts]]) for i in range(3)))
    coverage = coverage_samples(env, demos, rollouts, n_uniform=config.coverage_uniform, seed=config.seed)
    truth = true_reward(env_id, env)
    discount = float(ppo_settings.get("gamma", PPOConfig(env_id=env_id).gamma))

    lenses = {}
    for name, reward in rewards.items():
        epic: EpicResult | None = None
        if truth is not None:
            epic = epic_distance_sampled(
                torch_reward(reward), truth, coverage, coverage.observations, coverage.actions, discount, seed=config.seed, n_mean_samples=config.mean_samples
            )
        returns = [result["eval"]["mean_return"] for result in retrained[name]]
        lenses[name] = {
            "epic": epic.epic if epic else None,
            "pearson": epic.pearson if epic else None,
            "mean_return": float(np.mean(returns)) if returns else None,
            "normalized": normalized(float(np.mean(returns)), random_return, expert_return) if returns else None,
            "seed_returns": returns,
            "seed_normalized": [normalized(value, random_return, expert_return) for value in returns],
            "seed_runs": [str(Path(result["run"]).relative_to(out)) for result in retrained[name]],
        }

    plots: dict[str, str] = {}
    if truth is not None:
        plots["reward_scatter"] = "reward_scatter.png"
        true_values = truth(*coverage)
        plot_reward_scatter(out / plots["reward_scatter"], true_values, {name: torch_reward(reward)(*coverage) for name, reward in rewards.items()},
                            xlabel="true reward R(s, a, s')", title=f"{env_id}: rewards on the EPIC coverage batch")
    if isinstance(env.observation_space, gym.spaces.Box) and env.observation_space.shape and np.prod(env.observation_space.shape) >= 2:
        plots["state_slices"] = "state_slices.png"
        slices = {"recovered": torch_reward(model)} | ({"true": truth} if truth is not None else {})
        plot_state_slices(out / plots["state_slices"], demos.observations, demos.actions, slices, env.observation_space, title=f"{env_id}: reward over a 2-D slice of the state space")
    if steps > 0:
        plots["retrain_returns"] = "retrain_returns.png"
        plot_return_distributions(out / plots["retrain_returns"], {name: lenses[name]["seed_returns"] for name in rewards},
                                  {"demos": expert_return, "random policy": random_return}, title=f"{env_id}: true return after retraining PPO ({steps:,} steps)")
    return _results(
        lenses, references, retrain_steps=steps, seeds=seeds if steps > 0 else [],
        coverage={"kind": "sampled", "transitions": len(coverage.observations), "demo_transitions": len(demos), "rollout_transitions": len(rollouts.observations),
                  "uniform_transitions": config.coverage_uniform, "mean_samples": config.mean_samples, "discount": discount,
                  "true_reward": "known" if truth is not None else "unknown for this env: no EPIC"},
        plots=plots,
    )


def _policy_transitions(run: Path, env: gym.Env, *, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    from imitation.policies import SingleObservationPolicy, load_policy

    return collect_transitions(env, SingleObservationPolicy(load_policy(run)), episodes=ROLLOUT_EPISODES, seed=seed)


def _train_ppo_quietly(config: Any, out: Path) -> dict[str, Any]:
    """One retraining in a worker process (one torch thread, no progress bar)."""
    from imitation.training import ppo_job

    torch.set_num_threads(1)
    return ppo_job(config, out, progress=False)


def _run_ppo_jobs(jobs: list[tuple[str, int, Any, Path]], *, workers: int, progress: bool) -> list[tuple[str, dict[str, Any]]]:
    """Train every (name, seed, PPOConfig, out) job, `workers` at a time in fresh processes."""
    bar = tqdm(total=len(jobs), desc="retrain", unit="run", disable=None if progress else True, dynamic_ncols=True)
    results: list[tuple[str, dict[str, Any]]] = []
    with bar, ProcessPoolExecutor(max_workers=min(workers, len(jobs)), mp_context=get_context("spawn")) as pool:
        futures = [(name, pool.submit(_train_ppo_quietly, ppo_config, path)) for name, _, ppo_config, path in jobs]
        for name, future in futures:
            results.append((name, future.result()))
            bar.update()
    return results


# ------------------------------------------------------------------------------------------------
# Results and report


def _results(lenses: dict[str, dict[str, Any]], references: dict[str, Any], *, retrain_steps: int, seeds: list[Any], coverage: dict[str, Any], plots: dict[str, str]) -> dict[str, Any]:
    learned = lenses["learned"]
    return {
        "epic": learned["epic"],
        "pearson": learned["pearson"],
        "retrain": {"mean_return": learned["mean_return"], "normalized": learned["normalized"], "seeds": seeds, "steps": retrain_steps,
                    "seed_returns": learned.get("seed_returns", []), "seed_normalized": learned.get("seed_normalized", []),
                    "seed_runs": learned.get("seed_runs", [])},
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
    rows += [(f"control: {name} reward", c["epic"], c["pearson"], c["mean_return"], c["normalized"]) for name, c in controls.items()]
    how = ("exact soft-optimal policy for each reward (tabular MDP)" if results["coverage"]["kind"] == "exact"
           else f"PPO from scratch, {retrain['steps']:,} steps, seeds {retrain['seeds']}, deterministic evaluation")
    references = results["references"]
    lines = [
        f"{heading} Reward evaluation: `{results['run']}` on {results['env_id']}",
        "",
        f"Retraining: {how}. Normalised return = (R − R_random)/(R_expert − R_random) with R_expert = "
        f"{references['expert_return']:.2f} and R_random = {references['random_return']:.2f} ({references['source']}). "
        f"EPIC: 0 = the same task as the true reward, √½ ≈ 0.707 = unrelated, 1 = the opposite; coverage: {results['coverage']['kind']}, "
        f"{results['coverage']['transitions']:,} transitions.",
        "",
        "| reward | EPIC ↓ | Pearson ↑ | true return | normalised ↑ |",
        "|---|---:|---:|---:|---:|",
        *(f"| {name} | {_number(epic)} | {_number(pearson)} | {_number(value, 2)} | {_number(norm)} |" for name, epic, pearson, value, norm in rows),
        "",
    ]
    if retrain.get("seed_returns"):
        lines += ["Recovered reward, per seed: " + ", ".join(f"seed {s}: {r:.1f} ({n:.2f})" for s, r, n in zip(retrain["seeds"], retrain["seed_returns"], retrain["seed_normalized"])), ""]
    lines += [f"![{name}]({image_prefix}{file})" for name, file in results["plots"].items()]
    return "\n".join(lines) + "\n"
