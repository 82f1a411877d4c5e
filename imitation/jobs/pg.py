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
from imitation.envs.make import make_env
from imitation.evaluation.plots import plot_curve
from imitation.jobs.run_config import RunConfig, config_json
from imitation.jobs.run_directory import final_evaluation, save_policy, train_to_end, training_run
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
    # in, so it starts another: a batch is three episodes, 600 steps (REINFORCE, baseline).
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
        # A2C-style: rollouts of 2 steps on 8 copies make 31,250 small updates in 500k steps, where
        # whole episodes allow ~830; the entropy bonus keeps σ from collapsing before the swing-up.
        "actor-critic": dict(
            total_steps=500_000,
            n_envs=8,
            rollout_steps=2,
            learning_rate=2e-3,
            value_learning_rate=2e-3,
            value_steps=1,
            entropy_coef=0.1,
            max_grad_norm=0.5,
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
    if "batch_steps" in fields and "rollout_steps" not in fields:
        settings.pop("rollout_steps", None)  # a batch size asked for is one of whole episodes
    return PGConfig(env_id=env_id, **settings | fields)


def pg_job(config: PGConfig, out: str | os.PathLike, *, progress: bool = True, resume: bool = False) -> dict[str, Any]:
    """Train policy gradient into run directory `out`; the metrics also written to metrics.json.
    `resume` continues the interrupted run in `out`.partial from its checkpoint."""
    config.validate()
    seed_everything(config.seed)
    run_config = RunConfig(kind="pg", env_id=config.env_id, pg=config_json(config))
    with training_run(out, run_config, resume=resume) as run:
        learner = PolicyGradient(config)
        seconds = train_to_end(run, learner, progress=progress)
        save_policy(run, learner.policy, learner.reward_scaler)
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
