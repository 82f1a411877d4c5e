"""`eval reward`: is a recovered reward any good? Retrains policies on it and on two controls,
samples the coverage batch, and writes the lenses of `imitation.evaluation.reward` (metrics.json,
plots, report.md and the retrained runs) to one output directory."""

from __future__ import annotations

import dataclasses
import os
import sys
import time
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor
from contextlib import closing
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch

from imitation.algorithms.ppo import PPO, PPOConfig
from imitation.data.dataset import DemoDataset
from imitation.data.loader import load_transitions
from imitation.data.spaces import check_spaces_fit, describe_space
from imitation.envs.make import make_env
from imitation.envs.rollout import collect_transitions
from imitation.envs.tabular import TabularEnv
from imitation.envs.true_rewards import true_reward
from imitation.errors import ImitationError
from imitation.evaluation.epic import TransitionBatch, coverage_samples
from imitation.evaluation.policy import EVAL_SEED, reference_returns
from imitation.evaluation.report import write_report
from imitation.evaluation.reward import (
    Retraining,
    SampledEvaluation,
    evaluate_sampled_reward,
    evaluate_tabular_reward,
    reward_report,
    with_controls,
)
from imitation.experts.load import load_expert
from imitation.jobs.evaluate_reward_config import RewardEvaluationConfig
from imitation.jobs.ppo import ppo_job
from imitation.jobs.presets import ppo_settings, preset
from imitation.jobs.run_config import RunConfig, config_json
from imitation.policies import SingleObservationPolicy
from imitation.policy_kinds import load_policy
from imitation.progress import progress_bar
from imitation.ray_engine import RETRIES, Workers, ray_get
from imitation.rewards import RewardNet, read_reward_run
from imitation.runs import RunWriter, has_checkpoint

ROLLOUT_EPISODES = 4  # per policy, for the coverage batch


def evaluate_reward(
    run: str | os.PathLike,
    env_id: str,
    config: RewardEvaluationConfig,
    out: str | os.PathLike,
    *,
    progress: bool = True,
    workers: Workers | None = None,
) -> dict[str, Any]:
    """Evaluate the reward model of run directory `run` on `env_id`; write the results
    (metrics.json), plots and report.md to directory `out` (replaced only when complete).
    With `workers`, the PPO retrainings run as Ray tasks instead of local processes."""
    config.validate()
    saved = read_reward_run(run)
    model = saved.reward
    _check_flat_observations(model, run)
    run_config = RunConfig.from_json(saved.config)
    with closing(make_env(env_id)) as env:
        check_spaces_fit("reward model's", model.observation_space, model.action_space, env, where=f"{run}")
        writer_config = RunConfig(kind="reward-evaluation", env_id=env_id, run=str(run), evaluation=config_json(config))
        with RunWriter(out, config=writer_config.to_json(), tensorboard=False) as writer:
            if isinstance(env.unwrapped, TabularEnv):
                discount = float((run_config.irl or {}).get("discount", 1.0))
                results = evaluate_tabular_reward(
                    model, env.unwrapped.mdp, env_id, discount=discount, seed=config.seed, out=writer.partial
                )
            else:
                results = _evaluate_continuous(
                    model, env, env_id, run, run_config, config, writer.partial, progress=progress, workers=workers
                )
            results = {"run": str(run), "env_id": env_id, **results}
            write_report(writer.partial / "report.md", reward_report(results), title=f"Reward evaluation: {run} on {env_id}")
            writer.finish(results)
    return {"out": str(writer.path), **results}


def _check_flat_observations(model: RewardNet, run: str | os.PathLike) -> None:
    """Refuse, in one line, a reward of image or Dict observations (GCL on `record --pixels`
    demos): EPIC's coverage batch draws states uniformly and from arrays, which such a reward
    cannot read (a sampled state is no rendered frame)."""
    if model.layout is not None:
        raise ImitationError(
            f"{run}: eval reward does not support rewards of image or Dict observations yet (this one reads "
            f"{describe_space(model.observation_space)}): EPIC samples states, not frames; judge it by the policy that "
            f"train ppo --reward {run} learns (eval policy)"
        )


def _evaluate_continuous(
    model: RewardNet,
    env: gym.Env,
    env_id: str,
    run: str | os.PathLike,
    run_config: RunConfig,
    config: RewardEvaluationConfig,
    out: Path,
    *,
    progress: bool,
    workers: Workers | None,
) -> dict[str, Any]:
    demo_paths = config.demos if config.demos is not None else run_config.demos or []
    if not demo_paths:
        raise ImitationError(
            f"{run}: its config names no demos; pass --demos F.mcap (the expert reference and EPIC's coverage)"
        )
    dataset = DemoDataset(demo_paths)
    check_spaces_fit("demos'", dataset.observation_space, dataset.action_space, env, where=str(demo_paths[0]))
    demos = load_transitions(dataset, next_observations=True)
    references = reference_returns(env, demo_paths)
    random_policy = load_expert("random", env, seed=config.seed)  # for the coverage batch's rollouts

    rewards = with_controls(model, seed=config.seed)
    settings = ppo_settings(env_id, env.action_space, learned_reward=True)
    retraining = _retrain(rewards, run, env_id, settings, config, out, progress=progress, workers=workers)
    policy_rollouts = [_policy_transitions(out / path, env, seed=EVAL_SEED) for path in retraining.runs["learned"]]
    random_rollouts = collect_transitions(env, random_policy, episodes=ROLLOUT_EPISODES, seed=EVAL_SEED)
    rollouts = TransitionBatch(*(np.concatenate([part[i] for part in [random_rollouts, *policy_rollouts]]) for i in range(3)))
    # The demos' s, a, s' as arrays, as EPIC's coverage takes them: a reward model takes no Dict
    # spaces, and the next observations were loaded above.
    assert isinstance(demos.observations, np.ndarray) and isinstance(demos.actions, np.ndarray)
    assert isinstance(demos.next_observations, np.ndarray)
    demo_batch = TransitionBatch(demos.observations, demos.actions, demos.next_observations)
    coverage = coverage_samples(env, demo_batch, rollouts, n_uniform=config.coverage_uniform, seed=config.seed)
    return evaluate_sampled_reward(
        rewards,
        true_reward(env_id, env),
        coverage,
        env=env,
        env_id=env_id,
        discount=float(settings.get("gamma", PPOConfig(env_id=env_id).gamma)),
        demos=demos,
        rollout_transitions=len(rollouts.observations),
        retraining=retraining,
        references=references,
        config=SampledEvaluation(coverage_uniform=config.coverage_uniform, mean_samples=config.mean_samples, seed=config.seed),
        out=out,
    )


def _retrain(
    rewards: dict[str, RewardNet],
    run: str | os.PathLike,
    env_id: str,
    settings: dict[str, Any],
    config: RewardEvaluationConfig,
    out: Path,
    *,
    progress: bool,
    workers: Workers | None,
) -> Retraining:
    """PPO from scratch on each reward for `config.seeds` seeds, `config.jobs` at a time in fresh
    processes (or as tasks on `workers`' Ray), into `out`/retrain/NAME-seedS. The recovered reward
    is named by its run, so each retrained run says which reward it optimised; the controls go
    as they are."""
    steps = preset(env_id).retrain_steps if config.retrain_steps is None else config.retrain_steps
    seeds = list(range(config.seed, config.seed + config.seeds))
    retraining = Retraining(
        steps=steps, seeds=seeds, returns={name: [] for name in rewards}, runs={name: [] for name in rewards}
    )
    if steps == 0:
        return retraining
    jobs = []
    for name, reward in rewards.items():
        source = (
            {"reward_run": str(run)}
            if name == "learned"
            else {"reward": reward, "reward_source": f"eval reward control: {name} reward"}
        )
        for seed in seeds:
            ppo_config = PPOConfig(env_id=env_id, total_steps=steps, seed=seed, device="cpu", **settings)
            jobs.append((name, ppo_config, out / "retrain" / f"{name}-seed{seed}", source))
    parallel = min(workers.count if workers else config.jobs, len(jobs))
    retraining.estimated_seconds = _estimate_seconds(jobs[0][1], rewards["learned"], len(jobs), parallel)
    if progress:
        where = f"on {parallel} Ray workers" if workers else f"{parallel} at a time"
        print(
            f"[eval reward] retraining PPO from scratch: {len(rewards)} rewards × {len(seeds)} seed(s) × {steps:,} steps, "
            f"{where}; about {retraining.estimated_seconds / 60:.0f} min at the speed measured here",
            file=sys.stderr,
            flush=True,
        )
    bar = progress_bar(total=len(jobs), desc="retrain", unit="run", enabled=progress)
    with bar:
        for (name, *_), result in zip(jobs, _run_trainings([job[1:] for job in jobs], workers, parallel)):
            retraining.returns[name].append(result["eval"]["mean_return"])
            retraining.runs[name].append(str(Path(result["run"]).relative_to(out)))
            bar.update()
    return retraining


def _estimate_seconds(config: PPOConfig, reward: RewardNet, runs: int, workers: int) -> float:
    """How long `runs` retrainings take, `workers` at a time: two PPO updates on the reward, timed
    here (the first, which starts the environments and warms up, is left out), scaled up. Side by
    side runs share the machine's cores, so more workers than cores do not go faster. PPO seeds
    torch's generator: the probe runs on a fork of it, so what follows draws as it would without."""
    with torch.random.fork_rng(devices=[]):
        probe = PPO(dataclasses.replace(config, total_steps=2 * config.n_envs * config.n_steps), reward=reward)
        try:
            probe.step()
            started = time.perf_counter()
            probe.step()
            per_step = (time.perf_counter() - started) / (config.n_envs * config.n_steps)
        finally:
            probe.close()
    parallel = max(1, min(workers, os.cpu_count() or 1))
    return per_step * config.total_steps * runs / parallel


def _run_trainings(
    trainings: list[tuple[PPOConfig, Path, dict[str, Any]]], workers: Workers | None, parallel: int
) -> Iterator[dict[str, Any]]:
    """The result of `_train_ppo_quietly` for each training, in order: `parallel` fresh local
    processes at a time, or tasks on `workers`' Ray, each retried when its worker dies."""
    if workers is None:
        with ProcessPoolExecutor(max_workers=parallel, mp_context=get_context("spawn")) as pool:
            futures = [pool.submit(_train_ppo_quietly, *training) for training in trainings]
            yield from (future.result() for future in futures)
        return
    with workers.session() as ray:
        task = ray.remote(num_cpus=1, max_retries=RETRIES)(_train_ppo_quietly)
        pending = [task.remote(*training) for training in trainings]
        yield from (ray_get(ray, reference) for reference in pending)


def _train_ppo_quietly(config: PPOConfig, out: Path, source: dict[str, Any]) -> dict[str, Any]:
    """One retraining in a worker process (one torch thread, no progress bar). A retry of a
    training whose worker died continues from the checkpoint it left."""
    torch.set_num_threads(1)
    resume = has_checkpoint(out.with_name(out.name + ".partial"))
    return ppo_job(config, out, progress=False, resume=resume, **source)


def _policy_transitions(run: Path, env: gym.Env, *, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    return collect_transitions(env, SingleObservationPolicy(load_policy(run)), episodes=ROLLOUT_EPISODES, seed=seed)
