"""`train ppo`: the bundled PPO trainer on an env's reward or a learned one, into a run directory."""

from __future__ import annotations

import os
from contextlib import closing
from typing import Any

from imitation.algorithms.ppo import PPO, PPOConfig, make_observed_env
from imitation.data.spaces import check_spaces_fit
from imitation.evaluation.plots import plot_curve
from imitation.jobs.run_config import RunConfig, config_json
from imitation.jobs.run_directory import final_evaluation, save_policy, train_to_end, training_run
from imitation.policies import acting_env, make_acting_env
from imitation.rewards import RewardNet, load_reward
from imitation.runs import read_run
from imitation.seeding import seed_everything


def ppo_job(
    config: PPOConfig,
    out: str | os.PathLike,
    *,
    reward_run: str | None = None,
    reward: RewardNet | None = None,
    reward_source: str | None = None,
    progress: bool = True,
    resume: bool = False,
) -> dict[str, Any]:
    """Train PPO into run directory `out`; the metrics also written to metrics.json. It
    optimises the env's reward, or a learned one: the reward model of run directory
    `reward_run` (`train ppo --reward`), or `reward` itself (described by `reward_source`).
    `resume` continues the interrupted run in `out`.partial from its checkpoint."""
    config.validate()
    seed_everything(config.seed)
    demos = None
    if reward_run is not None:
        reward = load_reward(reward_run)
        demos = RunConfig.from_json(read_run(reward_run)[0]).existing_demos()  # the expert reference of `eval policy`
        reward_source = f"--reward {reward_run}"
    if reward is not None:
        with closing(
            make_observed_env(config.env_id, config.recipe, config.frame_stack)
        ) as env:  # fail before training, with one line
            check_spaces_fit(
                "reward model's", reward.observation_space, reward.action_space, env, where=reward_source or "the reward"
            )
    run_config = RunConfig(
        kind="ppo", env_id=config.env_id, reward_run=reward_run, demos=demos, source=reward_source, ppo=config_json(config)
    )
    with training_run(out, run_config, resume=resume) as run:
        learner = PPO(config, reward=reward)
        seconds = train_to_end(run, learner, progress=progress)
        save_policy(run, learner.policy, learner.reward_scaler.stats if learner.reward_scaler is not None else None)
        ys = ["return"] + (["optimised_return"] if reward is not None else [])
        plot_curve(
            run.file("learning_curve.png"), run.history, x="step", ys=ys, title=f"PPO ({config.objective}) on {config.env_id}"
        )
        policy = learner.policy.cpu()
        with closing(make_acting_env(policy.config, config.env_id)) as env:  # rendering frames for a pixel policy
            evaluation = final_evaluation(policy, acting_env(policy, env))
        metrics = {
            "env_id": config.env_id,
            "objective": config.objective,
            "steps": learner.global_step,
            "seconds": seconds,
            "steps_per_second": learner.global_step / seconds,
            "final_train_return": run.history[-1]["return"] if run.history else None,
            "eval": evaluation,
        }
        run.finish(metrics)
    return {"run": str(run.path), **metrics}
