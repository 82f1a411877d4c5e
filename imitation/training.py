"""Training jobs: an algorithm, its run directory, plots and a final evaluation, as one call.

The CLI calls these; learners in imitation.algorithms know nothing of run directories.
"""

from __future__ import annotations

import os
from typing import Any

import gymnasium as gym

from imitation import __version__
from imitation.algorithms.ppo import PPOConfig, train_ppo
from imitation.envs.make import make_env
from imitation.evaluation.policy import evaluate_policy
from imitation.policies import SingleObservationPolicy, policy_tensors
from imitation.rewards import LearnedReward, load_reward
from imitation.runs import RunWriter, plot_curve

EVAL_SEED = 10_000  # evaluation episodes start here, away from training and demo seeds
EVAL_EPISODES = 10


def ppo_job(config: PPOConfig, out: str | os.PathLike, *, progress: bool = True) -> dict[str, Any]:
    """Train PPO into run directory `out`; returns the metrics also written to metrics.json."""
    config.validate()
    wrap = None
    if config.reward_run is not None:
        reward_model = load_reward(config.reward_run)
        LearnedReward(make_env(config.env_id), reward_model, where=f"--reward {config.reward_run}")  # spaces check, one line

        def wrap(env: gym.Env) -> gym.Env:
            return LearnedReward(env, reward_model, where=f"--reward {config.reward_run}")

    run = RunWriter(out, config={"kind": "ppo", "env_id": config.env_id, "creator": f"imitation-mcap {__version__}", "ppo": vars(config).copy()})
    try:
        result = train_ppo(config, wrap_env=wrap, log=run.log, progress=progress)
        tensors = policy_tensors(result.policy)
        if result.reward_scaler is not None:
            tensors |= {f"reward_scaler.{name}": t for name, t in result.reward_scaler.stats.state_dict().items()}
        run.save_weights(tensors)
        run.update_config(policy=result.policy.config.to_json())
        ys = ["return"] + (["optimised_return"] if config.reward_run else [])
        plot_curve(run.file("learning_curve.png"), run.history, x="step", ys=ys, title=f"PPO ({config.objective}) on {config.env_id}")
        env = make_env(config.env_id)
        evaluation = evaluate_policy(SingleObservationPolicy(result.policy.cpu()), env, episodes=EVAL_EPISODES, seed=EVAL_SEED)
        env.close()
        metrics = {
            "env_id": config.env_id,
            "objective": config.objective,
            "steps": result.steps,
            "seconds": result.seconds,
            "steps_per_second": result.steps / result.seconds,
            "final_train_return": result.history[-1]["return"] if result.history else None,
            "eval": {key: value for key, value in evaluation.items() if key != "returns"},
        }
        run.finish(metrics)
    except BaseException:
        run.abort()
        raise
    return {"run": str(run.path), **metrics}
