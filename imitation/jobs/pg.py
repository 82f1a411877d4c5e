"""`train pg`: policy gradient (REINFORCE, with a baseline, actor-critic) into a run directory.

Per-environment and per-estimator defaults (`PG_PRESETS`, `pg_config`) make `train pg --env ID
--estimator E` work without other flags; the figures behind them are in bench/RESULTS.md.
"""

from __future__ import annotations

import os
from contextlib import closing
from typing import Any

import gymnasium as gym

from imitation.algorithms.policy_gradient import PGConfig, PolicyGradient
from imitation.checkpoints import prefixed
from imitation.envs.make import make_env
from imitation.evaluation.plots import plot_curve
from imitation.jobs.loop import run as run_learner
from imitation.jobs.run_config import RunConfig, config_json
from imitation.jobs.run_directory import checkpointing, final_evaluation, training_run
from imitation.policies import policy_tensors
from imitation.seeding import seed_everything

# PGConfig fields per env, then per estimator ("*": every estimator), over PGConfig's defaults.
PG_PRESETS: dict[str, dict[str, dict[str, Any]]] = {
    "CartPole-v1": {
        # Issue 18's budgets (300k, 200k steps) less the most a last batch can overshoot them by:
        # batch_steps - 1 steps, then each env copy finishing an episode of up to 500 steps.
        "*": dict(total_steps=296_000, n_envs=4, batch_steps=2000, learning_rate=5e-3),
        "actor-critic": dict(total_steps=197_000, batch_steps=1000),
    },
    # Small batches and a short horizon (γ = 0.9, as PPO's preset); the critic gets 20 regression
    # steps a batch. Both copies' 200-step episodes end on the same round, the first at 399 steps
    # in, so it starts another: a batch is three episodes, 600 steps.
    "Pendulum-v1": {
        "*": dict(
            total_steps=499_000,
            n_envs=2,
            batch_steps=400,
            gamma=0.9,
            normalize_observations=True,
            normalize_rewards=True,
            log_std_init=-0.5,
            learning_rate=1e-2,
            value_learning_rate=3e-3,
            value_steps=20,
        ),
    },
}
# Envs without a preset: Box actions get the continuous-control settings.
_CONTINUOUS: dict[str, Any] = dict(normalize_observations=True, normalize_rewards=True, learning_rate=3e-3)


def pg_settings(env_id: str, estimator: str, action_space: gym.Space | None = None) -> dict[str, Any]:
    """PGConfig fields for `env_id` and `estimator`: the env's preset (the continuous-control
    defaults for unknown envs with Box actions), its estimator's entries over its shared ones."""
    if env_id in PG_PRESETS:
        preset = PG_PRESETS[env_id]
        return dict(preset.get("*", {})) | dict(preset.get(estimator, {}))
    return dict(_CONTINUOUS) if isinstance(action_space, gym.spaces.Box) else {}


def pg_config(env_id: str, **fields: Any) -> PGConfig:
    """A PGConfig for `env_id`: its preset for the estimator in `fields` (default "baseline"),
    then `fields` over it. The env is made to read its action space."""
    estimator = fields.get("estimator", PGConfig.estimator)
    with closing(make_env(env_id)) as env:
        settings = pg_settings(env_id, estimator, env.action_space)
    return PGConfig(env_id=env_id, **settings | fields)


def pg_job(config: PGConfig, out: str | os.PathLike, *, progress: bool = True, resume: bool = False) -> dict[str, Any]:
    """Train policy gradient into run directory `out`; the metrics also written to metrics.json.
    `resume` continues the interrupted run in `out`.partial from its checkpoint."""
    config.validate()
    seed_everything(config.seed)
    run_config = RunConfig(kind="pg", env_id=config.env_id, pg=config_json(config))
    with training_run(out, run_config, resume=resume) as run:
        learner = PolicyGradient(config)
        try:
            run_learner(learner, checkpoints=checkpointing(run), log=run.log, progress=progress)
            seconds = learner.clock.seconds  # training only, not the evaluation below
        finally:
            learner.close()
        tensors = policy_tensors(learner.policy)
        if learner.reward_scaler is not None:
            tensors |= prefixed("reward_scaler", learner.reward_scaler.state_dict())
        run.save_weights(tensors)
        run.update_config(policy=learner.policy.config.to_json())
        plot_curve(
            run.file("learning_curve.png"),
            run.history,
            x="step",
            ys=["return"],
            title=f"policy gradient ({config.estimator}) on {config.env_id}",
        )
        with closing(make_env(config.env_id)) as env:
            evaluation = final_evaluation(learner.policy.cpu(), env)
        metrics = {
            "env_id": config.env_id,
            "estimator": config.estimator,
            "n_step": config.n_step,
            "gae_lambda": config.gae_lambda if config.estimator == "actor-critic" and config.n_step is None else None,
            "steps": learner.global_step,
            "batches": learner.batches,
            "seconds": seconds,
            "steps_per_second": learner.global_step / seconds if seconds > 0 else None,
            "final_train_return": run.history[-1]["return"] if run.history else None,
            "eval": evaluation,
        }
        run.finish(metrics)
    return {"run": str(run.path), **metrics}
