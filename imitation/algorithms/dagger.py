"""DAgger, dataset aggregation (theory notes §5.1; Ross, Gordon & Bagnell 2011).

    D ← expert demos (optional);  π̂_1 ← BC(D)  (or, without demos, round 1 runs the expert: β_1 = 1)
    for i = 1 … R:
        π_i = β_i π* + (1 - β_i) π̂_i          at each step the expert acts with probability β_i
        run π_i; label every visited state s with the expert's action π*(s)  →  D_i
        D ← D ∪ D_i;  π̂_{i+1} ← BC(D)

β schedules: linear β_i = max(0, 1 - (i-1)/R), exponential β_i = p^(i-1). The learner visits
its own state distribution and the expert says what it should have done there, which is what
removes BC's compounding error (the notes' O(εT²) → O(εT)).

Each round's labelled rollouts are written as an MCAP demo file (round-NN.mcap) whose actions
are the expert's labels, so the aggregate dataset stays on disk and can be reloaded; the
episodes' metadata record the round, β and which steps the expert actually drove.

With checkpoints, the learner, the β-mixture's generator, the label count, the logged rows and
the finished rounds' file names are saved after a round; a resumed run goes on with the next
round and trains on the finished rounds' files as they are. Each round's BC starts afresh from
its seed (a new optimiser, the normaliser refitted), and rollouts are reset with seeds fixed by
the round, so the resumed run ends exactly where an uninterrupted one does, as long as the
expert is deterministic (`random` and tabular soft-optimal experts restart their generators).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import gymnasium as gym
import numpy as np

from imitation.algorithms.bc import BCConfig, train_bc
from imitation.checkpoints import (
    CheckpointData,
    Checkpointing,
    StopAtBoundary,
    TrainingInterrupted,
    checked_counter,
    floats,
    prefixed,
    snapshot,
    unprefixed,
)
from imitation.data.loader import load_transitions, split_episodes, transitions_to_torch
from imitation.data.store import DemoDataset, DemoWriter
from imitation.data.types import Episode, stack_samples
from imitation.envs.make import control_period
from imitation.errors import ImitationError
from imitation.policies import ActorCritic, SingleObservationPolicy

SCHEDULES = ("linear", "exponential")
Policy = Callable[[Any], Any]


@dataclass(kw_only=True)
class DAggerConfig:
    rounds: int = 5
    episodes_per_round: int = 5
    beta_schedule: str = "linear"
    beta_decay: float = 0.5  # p of the exponential schedule
    seed: int = 0
    # Each round warm-starts from the previous learner, so it needs fewer epochs than BC from scratch.
    bc: BCConfig = field(default_factory=lambda: BCConfig(epochs=60, patience=15))

    def validate(self) -> None:
        if self.beta_schedule not in SCHEDULES:
            raise ImitationError(f"--beta-schedule must be one of {', '.join(SCHEDULES)}, got {self.beta_schedule!r}")
        if self.rounds < 1 or self.episodes_per_round < 1:
            raise ImitationError("--rounds and --episodes-per-round must be at least 1")
        if not 0.0 <= self.beta_decay <= 1.0:
            raise ImitationError(f"--beta-decay must be in [0, 1], got {self.beta_decay}")


def beta_for_round(round_index: int, config: DAggerConfig) -> float:
    """β_i for round i = 1 … R."""
    if config.beta_schedule == "linear":
        return max(0.0, 1.0 - (round_index - 1) / config.rounds)
    return config.beta_decay ** (round_index - 1)


def collect_round(
    env: gym.Env,
    learner: Policy | None,
    expert: Policy,
    *,
    beta: float,
    episodes: int,
    seed: int,
    rng: np.random.Generator,
    metadata: dict[str, Any],
) -> list[Episode]:
    """Roll out the β-mixture of expert and learner; every action stored is the expert's label."""
    collected = []
    for i in range(episodes):
        observation, _ = env.reset(seed=seed + i)
        observations, labels, rewards, expert_drove = [observation], [], [], []
        terminated = truncated = False
        while not (terminated or truncated):
            label = expert(observation)
            use_expert = learner is None or rng.random() < beta
            action = label if use_expert else learner(observation)
            observation, reward, terminated, truncated, _ = env.step(action)
            observations.append(observation)
            labels.append(label)
            rewards.append(float(reward))
            expert_drove.append(bool(use_expert))
        collected.append(
            Episode(
                observations=stack_samples(observations, env.observation_space),
                actions=stack_samples(labels, env.action_space),
                rewards=np.asarray(rewards),
                terminated=bool(terminated),
                truncated=bool(truncated) and not terminated,
                metadata={**metadata, "seed": seed + i, "expert_steps": int(sum(expert_drove))},
            )
        )
    return collected


@dataclass
class DAggerResult:
    policy: ActorCritic
    history: list[dict[str, float]]
    round_files: list[Path]


def train_dagger(
    env: gym.Env,
    expert: Policy,
    policy: ActorCritic,
    config: DAggerConfig,
    *,
    round_dir: str | os.PathLike,
    env_id: str,
    demos: Sequence[str | os.PathLike] = (),
    evaluate: Callable[[ActorCritic], float] | None = None,
    log: Callable[[dict[str, float]], None] | None = None,
    checkpoints: Checkpointing | None = None,
) -> DAggerResult:
    """Run DAgger; round files go to `round_dir`, and the aggregate (demos + rounds) trains BC.

    With `checkpoints`, a checkpoint is saved every tenth of the rounds (by default), Ctrl-C
    stops after the current round with a checkpoint saved (TrainingInterrupted), and a run given
    `checkpoints.resume` continues with the round after it."""
    config.validate()
    rng = np.random.default_rng(config.seed)
    round_dir = Path(round_dir)
    round_dir.mkdir(parents=True, exist_ok=True)
    files: list[Path] = []
    history: list[dict[str, float]] = []
    learner: Policy | None = None
    labels = 0
    first_round = 1
    with StopAtBoundary(enabled=checkpoints is not None) as stop:
        if checkpoints is not None and checkpoints.resume is not None:
            first_round, labels = restore_dagger_checkpoint(checkpoints.resume, policy=policy, rng=rng, round_dir=round_dir, files=files, history=history)
            first_round = checked_counter(first_round, "next round", 1, config.rounds + 1)
            learner = SingleObservationPolicy(policy, deterministic=True)
        elif demos:
            policy, _ = _fit(policy, list(demos), config)
            learner = SingleObservationPolicy(policy, deterministic=True)
        for round_index in range(first_round, config.rounds + 1):
            beta = beta_for_round(round_index, config)
            episodes = collect_round(
                env, learner, expert, beta=beta, episodes=config.episodes_per_round,
                seed=config.seed * 100_000 + round_index * 1_000, rng=rng, metadata={"round": round_index, "beta": beta},
            )
            path = round_dir / f"round-{round_index:02d}.mcap"
            with DemoWriter(
                path, env_id=env_id, observation_space=env.observation_space, action_space=env.action_space,
                dt=control_period(env), source=f"dagger round {round_index}", metadata={"round": round_index, "beta": beta},
            ) as writer:
                for episode in episodes:
                    writer.write(episode)
            files.append(path)
            labels += sum(len(episode) for episode in episodes)
            policy, validation_loss = _fit(policy, list(demos) + files, config)
            learner = SingleObservationPolicy(policy, deterministic=True)
            row = {
                "round": float(round_index),
                "beta": beta,
                "expert_labels": float(labels),
                "rollout_return": float(np.mean([episode.episode_return for episode in episodes])),
                "validation_loss": validation_loss,
                "return": evaluate(policy) if evaluate is not None else float("nan"),
            }
            history.append(row)
            if log is not None:
                log(row)
            # A checkpoint every tenth of the rounds; Ctrl-C stops here (a finished run just finishes).
            interrupted = stop.requested and round_index < config.rounds
            if checkpoints is not None and (interrupted or (round_index % checkpoints.interval(config.rounds) == 0 and round_index < config.rounds)):
                checkpoints.save(*dagger_checkpoint(round_index + 1, labels, policy=policy, rng=rng, files=files, history=history))
            if interrupted:
                raise TrainingInterrupted(f"DAgger stopped after round {round_index} of {config.rounds}")
    return DAggerResult(policy=policy, history=history, round_files=files)


def dagger_checkpoint(
    next_round: int, labels: int, *, policy: ActorCritic, rng: np.random.Generator, files: list[Path], history: list[dict[str, float]]
) -> CheckpointData:
    """Everything `restore_dagger_checkpoint` needs to go on with `next_round`: the learner, the
    mixture's generator, the label count, the rows and the finished rounds' files (by name: the
    run directory is renamed when it finishes)."""
    state = {
        "round": next_round, "labels": labels, "rng": rng.bit_generator.state, "round_files": [path.name for path in files], "history": history,
    }
    return snapshot(prefixed("policy", policy.state_dict()), state)


def restore_dagger_checkpoint(
    checkpoint: CheckpointData, *, policy: ActorCritic, rng: np.random.Generator, round_dir: Path, files: list[Path],
    history: list[dict[str, float]],
) -> tuple[int, int]:
    """Load a `dagger_checkpoint` (files and history are filled in place); returns (next round, labels so far)."""
    tensors, state = checkpoint
    try:
        policy.load_state_dict(unprefixed("policy", tensors))
        rng.bit_generator.state = state["rng"]
        files += [round_dir / name for name in state["round_files"]]
        history += [floats(row) for row in state["history"]]
        return int(state["round"]), int(state["labels"])
    except (KeyError, TypeError, ValueError, RuntimeError) as error:
        raise ImitationError(f"the checkpoint does not fit this DAgger run ({type(error).__name__}: {str(error).splitlines()[0]})") from None


def _fit(policy: ActorCritic, paths: list[str | os.PathLike], config: DAggerConfig) -> tuple[ActorCritic, float]:
    """BC on the aggregate dataset, warm-started from `policy`; the best validation loss."""
    dataset = DemoDataset(paths)
    train_ids, validation_ids = split_episodes(len(dataset), validation_fraction=config.bc.validation_fraction, seed=config.seed)
    train = transitions_to_torch(load_transitions(dataset, episodes=train_ids, next_observations=False))
    validation = transitions_to_torch(load_transitions(dataset, episodes=validation_ids, next_observations=False)) if validation_ids else None
    result = train_bc(policy, train, validation, config.bc, progress=False)
    losses = [row["validation_loss"] for row in result.history if np.isfinite(row["validation_loss"])]
    return result.policy, min(losses) if losses else float("nan")
