"""`train bc`: behavioural cloning on demo files into a run directory."""

from __future__ import annotations

import os
from contextlib import closing, nullcontext
from typing import Any

import torch

from imitation.algorithms.bc import BCConfig, BehaviouralCloning, policy_options
from imitation.data.dataset import DemoDataset
from imitation.data.loader import (
    TransitionTensors,
    load_transitions,
    split_episode_tails,
    split_episodes,
    transitions_to_torch,
)
from imitation.envs.make import make_env
from imitation.errors import ImitationError
from imitation.evaluation.baselines import baseline_scores, policy_scores
from imitation.evaluation.plots import plot_curve
from imitation.evaluation.policy import EVAL_SEED, evaluate_policy
from imitation.jobs.loop import run as run_learner
from imitation.jobs.run_config import RunConfig, config_json
from imitation.jobs.run_directory import check_demos_fit_env, checkpointing, final_evaluation, fingerprints, training_run
from imitation.policies import ActorCritic, SingleObservationPolicy, make_policy, policy_tensors
from imitation.seeding import seed_everything


def bc_job(
    demos: list[str],
    env_id: str | None,
    config: BCConfig,
    out: str | os.PathLike,
    *,
    progress: bool = True,
    resume: bool = False,
) -> dict[str, Any]:
    """Behavioural cloning on `demos` into run directory `out`.

    Without `env_id` it trains offline (recordings with no simulator behind them): the policy
    takes the demos' own spaces and the run reports the validation loss only, no returns.
    `resume` continues the interrupted run in `out`.partial from its checkpoint."""
    seed_everything(config.seed)
    dataset = DemoDataset(demos)
    env = make_env(env_id) if env_id else None
    if env is not None:
        check_demos_fit_env(dataset, env)
    elif dataset.num_transitions == 0:
        raise ImitationError(f"{dataset.files[0].path}: the demos hold no transitions (no episode, or only empty ones)")
    spaces = env if env is not None else dataset
    train, validation, split = _split(dataset, config, offline=env is None)
    try:
        policy = make_policy(spaces.observation_space, spaces.action_space, **policy_options(config, len(train)))
    except ImitationError as error:
        raise ImitationError(f"{f'--env {env_id}' if env is not None else dataset.files[0].path}: {error}") from None
    config.validate(policy.is_continuous)

    def env_return(candidate: ActorCritic) -> float:
        assert env is not None  # passed to the learner only with an env
        return evaluate_policy(SingleObservationPolicy(candidate), env, episodes=5, seed=EVAL_SEED)["mean_return"]

    run_config = RunConfig(
        kind="bc",
        env_id=env_id,
        offline=env is None,
        demos_env_id=dataset.env_id,
        demos=[str(p) for p in demos],
        demo_fingerprints=fingerprints(dataset),
        bc=config_json(config),
        policy=policy.config.to_json(),
        split=split,
    )
    with (
        closing(env) if env is not None else nullcontext(),
        training_run(out, run_config, x_axis="epoch", resume=resume) as run,
    ):
        learner = BehaviouralCloning(policy, train, validation, config, evaluate=env_return if env is not None else None)
        run_learner(learner, checkpoints=checkpointing(run), log=run.log, progress=progress)
        seconds = learner.clock.seconds  # training only, not the evaluation below
        run.save_weights(policy_tensors(learner.policy.cpu()))
        yardstick = _yardstick(learner, train, validation, config, spaces.action_space)
        title = f"BC on {env_id or dataset.env_id or 'offline demos'}"
        plot_curve(
            run.file("loss_curve.png"),
            run.history,
            x="epoch",
            ys=["train_loss", "validation_loss"],
            title=f"{title}: loss",
            references={f"{name} baseline": value for name, value in yardstick["references"].items()},
        )
        if env is not None:
            plot_curve(run.file("return_curve.png"), run.history, x="epoch", ys=["return"], title=f"{title}: return")
        metrics = {
            "env_id": env_id,
            "offline": env is None,
            "train_transitions": len(train),
            "validation_transitions": len(validation) if validation is not None else 0,
            "epochs": len(run.history),
            "best_epoch": learner.best_epoch,
            "best_validation_loss": min((row["validation_loss"] for row in run.history), default=None),
            "seconds": seconds,
            "samples_per_second": run.history[-1]["samples_per_second"],
            "stopped": yardstick["stopped"],
            "validation": yardstick["validation"],
            "baselines": yardstick["baselines"],
            "beats_baselines": yardstick["beats"],
            "warnings": yardstick["warnings"],
            "eval": final_evaluation(learner.policy.cpu(), env) if env is not None else None,
        }
        run.finish(metrics)
    return {"run": str(run.path), **metrics}


def _yardstick(
    learner: BehaviouralCloning,
    train: TransitionTensors,
    validation: TransitionTensors | None,
    config: BCConfig,
    action_space: Any,
) -> dict[str, Any]:
    """How the run ended, and the policy beside the trivial baselines on the held-out transitions
    (`imitation.evaluation.baselines`): scores, which baselines it beats (lower NLL and lower squared
    error or error rate), the baselines' values of the plotted loss, and what a user must be told."""
    warnings = []
    if learner.stopped:
        stopped = f"no better validation loss for {config.patience} epochs (best at epoch {learner.best_epoch})"
    else:
        stopped = f"epoch limit ({config.epochs})"
        if learner.best_epoch > config.epochs - max(1, config.epochs // 20):
            warnings.append(
                f"BC stopped at its epoch limit ({config.epochs}) while the validation loss was still improving "
                f"(best at epoch {learner.best_epoch}): more epochs would likely fit better"
            )
    if validation is None or not len(validation):
        return {"stopped": stopped, "validation": None, "baselines": {}, "beats": {}, "references": {}, "warnings": warnings}
    scores = policy_scores(learner.policy.cpu(), validation.to("cpu"))
    baselines = baseline_scores(train, validation, action_space)
    beats = {name: all(scores[key] < value for key, value in baseline.items()) for name, baseline in baselines.items()}
    loss = "mse" if config.loss == "mse" else "nll"
    references = {name: baseline[loss] for name, baseline in baselines.items() if loss in baseline}
    if beaten := [name for name, won in beats.items() if not won]:
        warnings.append(
            f"BC does not beat the {', '.join(beaten)} baseline{'s' if len(beaten) > 1 else ''} on the held-out transitions "
            f"(NLL {scores['nll']:.4g} against {', '.join(f'{baselines[name]["nll"]:.4g}' for name in beaten)})"
        )
    return {
        "stopped": stopped,
        "validation": scores,
        "baselines": baselines,
        "beats": beats,
        "references": references,
        "warnings": warnings,
    }


def _split(
    dataset: DemoDataset, config: BCConfig, *, offline: bool
) -> tuple[TransitionTensors, TransitionTensors | None, dict[str, Any]]:
    """Training and validation transitions: whole episodes held out; offline, where the
    validation loss is all a run reports, each episode's last steps when there are too few
    episodes to spare one (a single long recording)."""
    train_ids, validation_ids = split_episodes(len(dataset), validation_fraction=config.validation_fraction, seed=config.seed)
    if validation_ids or not offline or config.validation_fraction == 0:
        train = transitions_to_torch(load_transitions(dataset, episodes=train_ids, next_observations=False))
        validation = (
            transitions_to_torch(load_transitions(dataset, episodes=validation_ids, next_observations=False))
            if validation_ids
            else None
        )
        return train, validation, {"train_episodes": train_ids, "validation_episodes": validation_ids}
    every = load_transitions(dataset, next_observations=False)
    train_rows, validation_rows = split_episode_tails(every, validation_fraction=config.validation_fraction)
    tensors = transitions_to_torch(every)
    validation = tensors.select(torch.from_numpy(validation_rows)) if len(validation_rows) else None
    return (
        tensors.select(torch.from_numpy(train_rows)),
        validation,
        {
            "episode_tails": config.validation_fraction,
            "train_transitions": len(train_rows),
            "validation_transitions": len(validation_rows),
        },
    )
