"""What every training job does around its learner: open the run directory (or reopen it to
resume), hand the loop its checkpoints, check demos against the env, evaluate at the end."""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Protocol

import gymnasium as gym

from imitation.checkpoints import TrainingClock, prefixed
from imitation.data.dataset import DemoDataset
from imitation.data.spaces import check_spaces_fit
from imitation.errors import ImitationError
from imitation.evaluation.policy import EVAL_EPISODES, EVAL_SEED, evaluate_policy
from imitation.jobs.loop import Checkpointing, Learner, TrainingInterrupted
from imitation.jobs.loop import run as run_learner
from imitation.jobs.run_config import RunConfig
from imitation.policies import RunningMeanStd, SingleObservationPolicy, policy_tensors
from imitation.policy_protocol import ImitationPolicy
from imitation.rewards import RewardNet, reward_tensors
from imitation.runs import RunWriter, has_checkpoint

# What may differ between an interrupted run and its --resume: where and how fast it runs.
RESUME_IGNORE = (
    "creator",
    "ppo.device",
    "ppo.threads",
    "ppo.async_envs",
    "pg.device",
    "pg.threads",
    "search.threads",
    "bc.device",
    "bc.threads",
    "dagger.bc.device",
    "dagger.bc.threads",
)


@contextmanager
def training_run(
    out: str | os.PathLike, config: RunConfig, *, x_axis: str = "step", resume: bool = False
) -> Iterator[RunWriter]:
    """The run directory `out` being written (or its interrupted run reopened, with `resume`);
    Ctrl-C's message says where the checkpoint is and how to continue."""
    with RunWriter(out, config=config.to_json(), x_axis=x_axis, resume=resume, resume_ignore=RESUME_IGNORE) as run:
        try:
            yield run
        except TrainingInterrupted as stopped:
            raise TrainingInterrupted(
                f"{stopped}; its checkpoint is in {run.partial}: run the same command with --resume to continue"
            ) from None
        except KeyboardInterrupt:  # outside the steps: before the first, after the last, or a second Ctrl-C
            if not has_checkpoint(run.partial):
                raise
            raise TrainingInterrupted(
                f"stopped before the run was written; its last checkpoint is in {run.partial}: run the same command "
                "with --resume to continue"
            ) from None


def checkpointing(run: RunWriter, *, at_start: bool = False) -> Checkpointing:
    """Checkpoints into `run`, from the one it was reopened with (and before the first step, with
    `at_start`)."""
    start = run.save_start_checkpoint if at_start else None
    return Checkpointing(save=run.save_checkpoint, resume=run.resumed, at_start=start)


class EnvLearner(Learner, Protocol):
    """A learner that holds envs to close and a clock of its training time."""

    clock: TrainingClock

    def close(self) -> None: ...


def train_to_end(run: RunWriter, learner: EnvLearner, *, progress: bool) -> float:
    """Run `learner` to its end in `run`, from the checkpoint `run` was reopened with; its envs
    are closed whatever happens. Returns the seconds it trained, not counting what follows."""
    try:
        run_learner(learner, checkpoints=checkpointing(run), log=run.log, progress=progress)
        return learner.clock.seconds
    finally:
        learner.close()


def save_policy(run: RunWriter, policy: ImitationPolicy, reward_scaler: RunningMeanStd | None = None) -> None:
    """The trained policy as `eval policy` reads it: its weights (and the reward scaler's
    statistics, when rewards were scaled) and its config."""
    tensors = policy_tensors(policy)
    if reward_scaler is not None:
        tensors |= prefixed("reward_scaler", reward_scaler.state_dict())
    run.save_weights(tensors)
    run.update_config(policy=policy.config.to_json())


def fingerprints(dataset: DemoDataset | None) -> list[str]:
    """What the run records of its demo files' content, so that --resume can tell a change."""
    return [file.fingerprint for file in dataset.files] if dataset is not None else []


def check_demos_fit_env(dataset: DemoDataset, env: gym.Env) -> None:
    first = dataset.files[0].path
    if dataset.num_transitions == 0:
        raise ImitationError(f"{first}: the demos hold no transitions (no episode, or only empty ones)")
    check_spaces_fit("demos'", dataset.observation_space, dataset.action_space, env, where=str(first))


def final_evaluation(policy: ImitationPolicy, env: gym.Env) -> dict[str, Any]:
    """The deterministic evaluation every run records in metrics.json (returns list left out)."""
    evaluation = evaluate_policy(SingleObservationPolicy(policy), env, episodes=EVAL_EPISODES, seed=EVAL_SEED)
    return {key: value for key, value in evaluation.items() if key != "returns"}


def save_reward_run(model: RewardNet, path: str | os.PathLike, *, env_id: str, source: str) -> Path:
    """A reward run directory holding only `model`: what `train ppo --reward` and `eval reward` read."""
    config = RunConfig(kind="reward", env_id=env_id, source=source, reward=model.config.to_json())
    with RunWriter(path, config=config.to_json(), tensorboard=False) as run:
        run.save_weights(reward_tensors(model))
        return run.finish({"env_id": env_id, "source": source})
