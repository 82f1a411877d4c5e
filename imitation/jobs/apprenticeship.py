"""`train irl --method apprenticeship`: feature-matching apprenticeship learning (projection
method) into a reward run directory, exact on a tabular env, with PPO on Box observations.

The run directory holds, in model.safetensors:

- `reward.*`: the recovered reward r = wᵀφ as a RewardNet (for `train ppo --reward` and `eval
  reward`), with w = w^(j) of the iteration j whose policy π^(j) is the mixture member nearest
  the expert (‖μ^(j) - μ_E‖₂ least, the random π^(0) left out): the reward under which the
  policy that matches the demos best was found optimal. Every w^(i) is in metrics.json.
- `policy.*`: that member π^(j), as the run's policy for `eval policy`. On a tabular env the
  optimal policy is time-indexed and a policy network sees the state alone, so the member is
  saved as its first-step decision π^(j)_0(s), played at every step; metrics.json gives the
  exact return of both.
- `mixture.*`: every member π^(0) … π^(n) (tabular: `mixture.policies`, (n+1, H, S, A); Box:
  `mixture.policy{i}.*`), their weights `mixture.lambdas` λ, feature expectations
  `mixture.feature_expectations` and the reward weights `mixture.reward_weights` w^(1) … w^(n).

metrics.json records the mixture's evaluation: its return Σ_j λ_j R(π^(j)) (the mixture picks
π^(j) with probability λ_j per episode), exact on a tabular env, else from each member's
deterministic evaluation episodes, and normalised between a random policy (0) and the expert (1).
"""

from __future__ import annotations

import os
from contextlib import closing
from dataclasses import replace
from typing import Any

import gymnasium as gym
import numpy as np
import torch

from imitation.algorithms.apprenticeship import (
    Apprenticeship,
    ApprenticeshipConfig,
    PPOSolver,
    TabularSolver,
    box_feature_reward,
    box_feature_scales,
    discounted_feature_sum,
    mixture_summary,
    reward_features,
    set_reward_weights,
    tabular_feature_reward,
)
from imitation.algorithms.maxent_irl import demo_visitation
from imitation.algorithms.ppo import PPOConfig
from imitation.checkpoints import prefixed
from imitation.data.dataset import DemoDataset
from imitation.data.loader import check_episodes_finite
from imitation.envs.make import make_env
from imitation.envs.tabular import TabularEnv, TabularMDP
from imitation.envs.tabular_planning import Dynamics, expected_return, soft_optimal_policy
from imitation.errors import ImitationError
from imitation.evaluation.plots import plot_curve, plot_grid_maps
from imitation.evaluation.policy import normalized, reference_returns
from imitation.jobs.loop import run as run_learner
from imitation.jobs.run_config import RunConfig, config_json
from imitation.jobs.run_directory import check_demos_fit_env, checkpointing, final_evaluation, fingerprints, training_run
from imitation.policies import ActorCritic, make_policy, policy_tensors
from imitation.rewards import RewardNet, reward_tensors
from imitation.runs import RunWriter
from imitation.seeding import seed_everything


def apprenticeship_job(
    demos: list[str],
    env_id: str,
    config: ApprenticeshipConfig,
    ppo_config: PPOConfig,
    out: str | os.PathLike,
    *,
    progress: bool = True,
    resume: bool = False,
) -> dict[str, Any]:
    """Apprenticeship learning on `demos` of `env_id` into run directory `out`: exact on a
    tabular env (`ppo_config` unused), with PPO (`ppo_config`, `config.solver_steps` steps per
    iteration) on Box observations. `resume` continues the interrupted run in `out`.partial."""
    config.validate()
    seed_everything(config.seed)
    with closing(make_env(env_id)) as env:
        tabular = isinstance(env.unwrapped, TabularEnv)
        if not tabular and not isinstance(env.observation_space, gym.spaces.Box):
            raise ImitationError(
                f"--method apprenticeship: {env_id} is neither a tabular MDP nor an env of Box observations "
                f"({type(env.observation_space).__name__}), so it has no features to match"
            )
        dataset = DemoDataset(demos)
        check_demos_fit_env(dataset, env)
    episodes = dataset.read_episodes()
    check_episodes_finite(episodes, dataset)
    if tabular:
        return _tabular(demos, dataset, episodes, env_id, config, out, progress=progress, resume=resume)
    return _sampled(demos, dataset, episodes, env_id, config, ppo_config, out, progress=progress, resume=resume)


def _run_config(
    demos: list[str], dataset: DemoDataset, env_id: str, config: ApprenticeshipConfig, reward: RewardNet, **extra: Any
) -> RunConfig:
    return RunConfig(
        kind="reward",
        env_id=env_id,
        demos=[str(path) for path in demos],
        demo_fingerprints=fingerprints(dataset),
        irl={"method": "apprenticeship", **config_json(config)},
        reward=reward.config.to_json(),
        **extra,
    )


def _learn(run: RunWriter, learner: Apprenticeship, progress: bool) -> None:
    # One checkpoint per iteration: an iteration of the PPO solver is minutes of training.
    checkpoints = checkpointing(run)
    checkpoints.every = 1
    run_learner(learner, checkpoints=checkpoints, log=run.log, progress=progress)


def _matching(learner: Apprenticeship) -> dict[str, Any]:
    """How well the mixture matches μ_E, and which member the run keeps."""
    chosen = learner.closest()
    scale = float(np.linalg.norm(learner.mu_expert))
    return {
        "iterations": learner.iterations,
        "converged": learner.converged,
        "stalled": learner.stalled,
        "feature_distance": learner.distance,
        "relative_feature_distance": learner.distance / scale if scale > 0 else learner.distance,
        "chosen_member": chosen,
        "chosen_member_feature_distance": float(np.linalg.norm(learner.mus[chosen] - learner.mu_expert)),
        "seconds": learner.clock.seconds,
    }


def _plot(run: RunWriter, env_id: str) -> None:
    plot_curve(
        run.file("irl_curve.png"),
        run.history,
        x="iteration",
        ys=["relative_distance", "alpha"],
        title=f"apprenticeship learning on {env_id}: ‖μ_E - μ̄‖/‖μ_E‖",
    )


def stationary_policy(
    mdp: TabularMDP, observation_space: gym.Space, action_space: gym.Space, first_step: np.ndarray
) -> ActorCritic:
    """A linear policy network on one-hot states that acts by π_0(a|s) (S, A): its logits are
    20·π_0(a|s), so the deterministic action is π_0's and a sampled one π_0's with odds e^20."""
    policy = make_policy(observation_space, action_space, hidden_sizes=[])
    with torch.no_grad():
        policy.action_head.weight.copy_(torch.as_tensor(20.0 * first_step.T, dtype=torch.float32))
        policy.action_head.bias.zero_()
    return policy


def _tabular(
    demos: list[str],
    dataset: DemoDataset,
    episodes: list[Any],
    env_id: str,
    config: ApprenticeshipConfig,
    out: str | os.PathLike,
    *,
    progress: bool,
    resume: bool,
) -> dict[str, Any]:
    with closing(make_env(env_id)) as env:
        unwrapped = env.unwrapped
        assert isinstance(unwrapped, TabularEnv)  # apprenticeship_job sent only tabular envs here
        mdp, observation_space, action_space = unwrapped.mdp, env.observation_space, env.action_space
    occupancy = demo_visitation(episodes, n_states=mdp.n_states, horizon=mdp.horizon, discount=config.discount)
    mu_expert = occupancy @ mdp.features
    reward = tabular_feature_reward(observation_space, action_space, mdp.features)
    with training_run(out, _run_config(demos, dataset, env_id, config, reward), x_axis="iteration", resume=resume) as run:
        solver = TabularSolver(mdp, config.discount)
        learner = Apprenticeship(solver, mu_expert, config)
        _learn(run, learner, progress)
        matching = _matching(learner)
        chosen = matching["chosen_member"]
        weights = learner.weights[chosen - 1]
        set_reward_weights(reward, weights)
        members = np.stack(solver.policies)
        first_step = members[chosen] if mdp.horizon is None else members[chosen][0]
        policy = stationary_policy(mdp, observation_space, action_space, first_step)
        run.save_weights(
            reward_tensors(reward)
            | policy_tensors(policy)
            | prefixed("mixture", _mixture_tensors(learner) | {"policies": torch.as_tensor(members, dtype=torch.float32)})
        )
        run.update_config(policy=policy.config.to_json())

        dynamics = Dynamics.of(mdp.transition)
        returns = np.array([expected_return(dynamics, mdp, _timed(mdp, member)) for member in members])
        expert = expected_return(dynamics, mdp, soft_optimal_policy(mdp))
        random = returns[0]  # π^(0) is the uniform random policy
        mixture_return = float(learner.lambdas @ returns)
        stationary_return = expected_return(dynamics, mdp, _timed(mdp, first_step))
        _plot(run, env_id)
        if mdp.grid_shape is not None:
            plot_grid_maps(
                run.file("reward_maps.png"),
                {"true reward": mdp.reward, "recovered reward": mdp.features @ weights},
                grid_shape=mdp.grid_shape,
                title=env_id,
            )
        metrics = {
            "env_id": env_id,
            "method": "apprenticeship",
            "solver": "value iteration (exact feature expectations)",
            "demo_episodes": len(dataset),
            **matching,
            "reward_weights": weights.tolist(),
            "feature_names": list(mdp.feature_names) if mdp.feature_names is not None else None,
            "mixture": {
                "return": mixture_return,
                "normalized_return": normalized(mixture_return, random, expert),
                "member_returns": returns.tolist(),
                **mixture_summary(learner),
            },
            "policy": {
                "member_return": float(returns[chosen]),
                "member_normalized_return": normalized(float(returns[chosen]), random, expert),
                "stationary_return": stationary_return,
                "stationary_normalized_return": normalized(stationary_return, random, expert),
            },
            "expert_return": expert,
            "random_return": float(random),
            "normalization": "exact returns; 0: the uniform random policy, 1: the soft-optimal policy for the true reward "
            "(the demos' expert)",
        }
        run.finish(metrics)
    return {"run": str(run.path), **metrics}


def _timed(mdp: TabularMDP, policy: np.ndarray) -> np.ndarray:
    """A stationary (S, A) policy repeated over the horizon, as `expected_return` takes it."""
    if policy.ndim == 3:
        return policy
    assert mdp.horizon is not None  # TabularEnv requires a finite horizon
    return np.broadcast_to(policy, (mdp.horizon, *policy.shape))


def _mixture_tensors(learner: Apprenticeship) -> dict[str, torch.Tensor]:
    return {
        "lambdas": torch.as_tensor(learner.lambdas),
        "feature_expectations": torch.as_tensor(learner.mus),
        "reward_weights": torch.as_tensor(learner.weights),
    }


def _sampled(
    demos: list[str],
    dataset: DemoDataset,
    episodes: list[Any],
    env_id: str,
    config: ApprenticeshipConfig,
    ppo_config: PPOConfig,
    out: str | os.PathLike,
    *,
    progress: bool,
    resume: bool,
) -> dict[str, Any]:
    solver_config = replace(ppo_config, total_steps=config.solver_steps)
    solver_config.validate()
    with closing(make_env(env_id)) as env:
        observation_space, action_space = env.observation_space, env.action_space
        assert isinstance(observation_space, gym.spaces.Box)  # apprenticeship_job sent only Box envs here
    observations = [np.asarray(episode.observations, dtype=np.float32) for episode in episodes]
    reward = box_feature_reward(
        observation_space, action_space, box_feature_scales(observation_space, np.concatenate(observations))
    )
    mu_expert = np.mean([discounted_feature_sum(reward_features(reward, o), config.discount) for o in observations], axis=0)
    run_config = _run_config(demos, dataset, env_id, config, reward, ppo=config_json(solver_config))
    with training_run(out, run_config, x_axis="iteration", resume=resume) as run:
        solver = PPOSolver(solver_config, reward, config)
        learner = Apprenticeship(solver, mu_expert, config)
        _learn(run, learner, progress)
        matching = _matching(learner)
        chosen = matching["chosen_member"]
        weights = learner.weights[chosen - 1]
        set_reward_weights(reward, weights)
        policy = solver.policies[chosen]
        members: dict[str, torch.Tensor] = {}
        for index, member in enumerate(solver.policies):
            # Copies: the chosen member's tensors are saved under `policy.` too, and safetensors refuses shared memory.
            members |= prefixed(f"policy{index}", {name: tensor.clone() for name, tensor in member.state_dict().items()})
        run.save_weights(
            reward_tensors(reward) | policy_tensors(policy) | prefixed("mixture", _mixture_tensors(learner) | members)
        )
        run.update_config(policy=policy.config.to_json())
        with closing(make_env(env_id)) as env:
            evaluations = [final_evaluation(member, env) for member in solver.policies]
            reference = reference_returns(env, [str(path) for path in demos])
        returns = np.array([evaluation["mean_return"] for evaluation in evaluations])
        mixture_return = float(learner.lambdas @ returns)
        _plot(run, env_id)
        ends = (reference["random_return"], reference["expert_return"])
        metrics = {
            "env_id": env_id,
            "method": "apprenticeship",
            "solver": "PPO (sampled feature expectations)",
            "demo_episodes": len(dataset),
            **matching,
            "steps": solver.steps,
            "reward_weights": weights.tolist(),
            "features": "relu(s/c), relu(-s/c) per observation coordinate",
            "mixture": {
                "return": mixture_return,
                "normalized_return": normalized(mixture_return, *ends),
                "member_returns": returns.tolist(),
                **mixture_summary(learner),
            },
            "eval": evaluations[chosen],
            "normalized_return": normalized(float(returns[chosen]), *ends),
            "reference": reference,
        }
        run.finish(metrics)
    return {"run": str(run.path), **metrics}
