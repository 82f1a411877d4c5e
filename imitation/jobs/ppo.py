"""`train ppo`: the bundled PPO trainer on an env's reward or a learned one, into a run directory."""

from __future__ import annotations

import json
import os
from contextlib import closing
from pathlib import Path
from typing import Any

from imitation.algorithms.ppo import PPO, PPOConfig, RolloutReward
from imitation.algorithms.ray_rollouts import RayRollouts
from imitation.data.spaces import check_spaces_fit
from imitation.envs.pixels import PixelRecipe
from imitation.envs.vector import make_observed_env
from imitation.errors import ImitationError
from imitation.evaluation.plots import plot_curve
from imitation.jobs.presets import ppo_config
from imitation.jobs.run_config import RunConfig, config_json
from imitation.jobs.run_directory import final_evaluation, save_policy, train_to_end, training_run
from imitation.policies import acting_env, make_acting_env
from imitation.ray_engine import Workers, worker_session
from imitation.rewards import RewardNet, RewardRun, ShapedReward, read_reward_run
from imitation.seeding import seed_everything


def ppo_job(
    config: PPOConfig,
    out: str | os.PathLike,
    *,
    reward_run: str | os.PathLike | RewardRun | None = None,
    shaped: bool = False,
    reward: RewardNet | None = None,
    reward_source: str | None = None,
    progress: bool = True,
    resume: bool = False,
    workers: Workers | None = None,
) -> dict[str, Any]:
    """Train PPO into run directory `out`; the metrics also written to metrics.json. It
    optimises the env's reward, or a learned one: the reward model of run directory
    `reward_run` (`train ppo --reward`, a path or the run already read; with `shaped`, AIRL's f,
    its g shaped by the potential h it learnt, at this PPO's γ), or `reward` itself (described by
    `reward_source`).
    `resume` continues the interrupted run in `out`.partial from its checkpoint. With
    `workers`, the rollouts run on that many Ray actors (`imitation.algorithms.ray_rollouts`)."""
    config.validate()
    seed_everything(config.seed)
    demos = None
    learned: RolloutReward | None = reward
    saved = reward_run if reward_run is None or isinstance(reward_run, RewardRun) else read_reward_run(reward_run)
    if saved is not None:
        learned = reward = saved.reward
        demos = RunConfig.from_json(saved.config).existing_demos()  # the expert reference of `eval policy`
        reward_source = f"--reward {saved.path}"
        if shaped:
            learned = ShapedReward(reward, saved.potential(), gamma=config.gamma)
            reward_source += " --shaped"
    elif shaped:
        raise ImitationError("--shaped: shapes the reward of an AIRL run, and no --reward was given")
    if reward is not None:
        with closing(
            make_observed_env(config.env_id, config.recipe, config.frame_stack)
        ) as env:  # fail before training, with one line
            check_spaces_fit(
                "reward model's", reward.observation_space, reward.action_space, env, where=reward_source or "the reward"
            )
    run_config = RunConfig(
        kind="ppo",
        env_id=config.env_id,
        reward_run=saved.path if saved else None,
        demos=demos,
        source=reward_source,
        ppo=config_json(config),
    )
    remote = RayRollouts(config.n_envs, workers.count) if workers else None
    with training_run(out, run_config, resume=resume) as run, worker_session(workers):
        learner = PPO(config, reward=learned, remote=remote)
        with closing(learner):
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
            "workers": workers.count if workers else None,
            "final_train_return": run.history[-1]["return"] if run.history else None,
            "eval": evaluation,
        }
        run.finish(metrics)
    return {"run": str(run.path), **metrics}


def train_ppo(
    env_id: str,
    out: str | os.PathLike,
    flags: dict[str, Any],
    *,
    reward_run: str | None = None,
    shaped: bool = False,
    resume: bool = False,
    progress: bool = True,
    workers: Workers | None = None,
) -> tuple[PPOConfig, dict[str, Any]]:
    """`train ppo`: the PPOConfig fields its `flags` set, completed by how a pixel reward and an
    interrupted run observe the env (`observation_fields`) and by the env's preset, then
    `ppo_job`; the reward run is read once. The config and the job's result."""
    saved = read_reward_run(reward_run) if reward_run is not None else None
    fields = observation_fields(flags, reward_run=saved, resume=out if resume else None)
    config = ppo_config(env_id, learned_reward=saved is not None, **fields)
    result = ppo_job(config, out, reward_run=saved, shaped=shaped, progress=progress, resume=resume, workers=workers)
    return config, result


# The PPOConfig fields that say how the env is observed. A pixel reward fixes them (it reads the
# frames it was learnt on), and so does the interrupted run that --resume continues.
OBSERVATION_FIELDS = ("pixels", "frame_stack", "observation_keys")


def observation_fields(
    given: dict[str, Any], *, reward_run: RewardRun | None = None, resume: str | os.PathLike | None = None
) -> dict[str, Any]:
    """PPOConfig fields `given` (by flags), completed with how the env must be observed: as the
    reward model of `reward_run` was learnt (its pixel recipe, frame stack and observation keys)
    and as the interrupted run `resume` (its --out) was started. A value that disagrees with one
    of them is refused in one line naming both."""
    fields = dict(given)
    origins = {name: "" for name in given}  # "": a flag
    for source, verb, required in (_reward_observation(reward_run), _resumed_observation(resume)):
        for name, value in required.items():
            if name in fields and fields[name] != value:
                raise ImitationError(_disagreement(name, fields[name], origins[name], f"{source}, {verb}", value))
            fields[name] = value
            origins.setdefault(name, source)
    return fields


def _reward_observation(reward_run: RewardRun | None) -> tuple[str, str, dict[str, Any]]:
    """(source, verb, the observation fields) of the reward model of `reward_run`."""
    if reward_run is None:
        return "", "", {}
    config = reward_run.reward.config
    required = {"pixels": config.pixels, "frame_stack": config.frame_stack, "observation_keys": config.observation_keys}
    return f"the reward model of {reward_run.path}", "learnt on", required


def _resumed_observation(out: str | os.PathLike | None) -> tuple[str, str, dict[str, Any]]:
    """(source, verb, the observation fields) of the interrupted run in `out`.partial (named as
    RunWriter names it); none when there is no readable one, which RunWriter then reports."""
    if out is None:
        return "", "", {}
    partial = Path(out).with_name(Path(out).name + ".partial")
    try:
        ppo = json.loads((partial / "config.json").read_text()).get("ppo")
    except (OSError, ValueError, AttributeError):
        return "", "", {}
    required = {name: ppo[name] for name in OBSERVATION_FIELDS if name in ppo} if isinstance(ppo, dict) else {}
    return f"the interrupted run in {partial}", "started with", required


def _disagreement(name: str, value: Any, origin: str, source: str, required: Any) -> str:
    """The one line refusing `value` of field `name` (from a flag, or from `origin`)."""
    mine = f"{_shown(name, value)} (from {origin})" if origin else _shown(name, value)
    remedy = "start again without --resume" if origin else "leave the flag out, or give the same"
    return f"{mine} disagrees with {source} {_shown(name, required)}: {remedy}"


def _shown(name: str, value: Any) -> str:
    """An observation field's value in the words of train ppo's flags."""
    if name == "frame_stack":
        return f"--frame-stack {value}"
    if name != "pixels":
        return f"observation keys {value}"
    if value is None:
        return "no --pixels"
    try:
        recipe = PixelRecipe.from_json(value)
    except ValueError:
        return f"pixels {str(value)[:80]}"
    crop = f" --crop {','.join(map(str, recipe.crop))}" if recipe.crop is not None else ""
    return f"--pixels {recipe.height}x{recipe.width}{' --grayscale' if recipe.grayscale else ''}{crop}"
