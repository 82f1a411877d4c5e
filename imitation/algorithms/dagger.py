"""DAgger, dataset aggregation (docs/THEORY.md §5.2; Ross, Gordon & Bagnell 2011).

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

With pixel observations the learner acts on stacks of frames (`StackFrames`) while a round file
holds single frames, the newest of each stack, and BC restacks them (`stack_frames`): what the
learner trains on is exactly what it saw.

The state saved after a round is the learner, the β-mixture's generator, the label count and
the finished rounds' file names; a resumed run goes on with the next round and trains on the
finished rounds' files as they are. Each round's BC starts afresh from
its seed (a new optimiser, the normaliser refitted), and rollouts are reset with seeds fixed by
the round, so the resumed run ends exactly where an uninterrupted one does, as long as the
expert is deterministic (`random` and tabular soft-optimal experts restart their generators).
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import gymnasium as gym
import numpy as np

from imitation.algorithms.bc import BCConfig, BehaviouralCloning, fit
from imitation.checkpoints import CheckpointData, checked_counter, prefixed, restoring, unprefixed
from imitation.data.dataset import DemoDataset
from imitation.data.loader import TransitionTensors, load_transitions, split_episodes, transitions_to_torch
from imitation.data.mcap.writer import DemoWriter
from imitation.data.types import Episode, stack_samples
from imitation.envs.make import control_period
from imitation.envs.pixels import StackFrames, stack_frames
from imitation.errors import ConfigError
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
            raise ConfigError(
                "beta_schedule", f"must be one of {', '.join(SCHEDULES)}, got {self.beta_schedule!r}", owner="DAggerConfig"
            )
        for name in ("rounds", "episodes_per_round"):
            if getattr(self, name) < 1:
                raise ConfigError(name, f"must be at least 1, got {getattr(self, name)}", owner="DAggerConfig")
        if not 0.0 <= self.beta_decay <= 1.0:
            raise ConfigError("beta_decay", f"must be in [0, 1], got {self.beta_decay}", owner="DAggerConfig")


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
            action = label if use_expert or learner is None else learner(observation)
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


class DAgger:
    """The learner: one round per step (roll out the β-mixture, write the round's labelled
    episodes to `round_dir`, retrain BC on the demos and every round so far)."""

    name = "DAgger"
    unit = "round"

    def __init__(
        self,
        env: gym.Env,
        expert: Policy,
        policy: ActorCritic,
        config: DAggerConfig,
        *,
        round_dir: str | os.PathLike,
        env_id: str,
        demos: Sequence[str | os.PathLike] = (),
        evaluate: Callable[[ActorCritic], float] | None = None,
        metadata: dict[str, Any] | None = None,
    ) -> None:
        config.validate()
        self.env, self.expert, self.policy, self.config = env, expert, policy, config
        # A StackFrames env's observations are stacks; the round files hold their newest frames.
        self.stacked_keys = env.keys if isinstance(env, StackFrames) else []
        self.frames = env.frames if isinstance(env, StackFrames) else 1
        self.file_space = env.env.observation_space if isinstance(env, StackFrames) else env.observation_space
        self.metadata = metadata or {}
        self.env_id, self.demos, self.evaluate = env_id, list(demos), evaluate
        self.total = config.rounds
        self.rng = np.random.default_rng(config.seed)
        self.round_dir = Path(round_dir)
        self.round_dir.mkdir(parents=True, exist_ok=True)
        self.files: list[Path] = []
        self.rounds = 0
        self.labels = 0
        self.learner: Policy | None = None

    @property
    def completed(self) -> int:
        return self.rounds

    @property
    def done(self) -> bool:
        return self.rounds >= self.total

    def position(self) -> str:
        return f"round {self.rounds} of {self.total}"

    def progress(self, row: dict[str, float]) -> dict[str, str]:
        return {"beta": f"{row['beta']:.2f}", "labels": str(int(row["expert_labels"])), "ret": f"{row['return']:.1f}"}

    def step(self) -> dict[str, float]:
        """Round i: π_i = β_i π* + (1 - β_i) π̂_i rolled out and labelled by π*, D ← D ∪ D_i, π̂_{i+1} ← BC(D)."""
        if self.learner is None and self.demos:
            self.policy, _ = self._fit(self.demos)  # π̂_1 ← BC(demos)
            self.learner = SingleObservationPolicy(self.policy, deterministic=True)
        round_index = self.rounds + 1
        beta = beta_for_round(round_index, self.config)
        episodes = collect_round(
            self.env,
            self.learner,
            self.expert,
            beta=beta,
            episodes=self.config.episodes_per_round,
            seed=self.config.seed * 100_000 + round_index * 1_000,
            rng=self.rng,
            metadata={"round": round_index, "beta": beta},
        )
        path = self.round_dir / f"round-{round_index:02d}.mcap"
        with DemoWriter(
            path,
            env_id=self.env_id,
            observation_space=self.file_space,
            action_space=self.env.action_space,
            dt=control_period(self.env),
            source=f"dagger round {round_index}",
            metadata={**self.metadata, "round": round_index, "beta": beta},
        ) as writer:
            for episode in episodes:
                writer.write(self._newest_frames(episode))
        self.files.append(path)
        self.labels += sum(len(episode) for episode in episodes)
        self.policy, validation_loss = self._fit([*self.demos, *self.files])
        self.learner = SingleObservationPolicy(self.policy, deterministic=True)
        self.rounds = round_index
        return {
            "round": float(round_index),
            "beta": beta,
            "expert_labels": float(self.labels),
            "rollout_return": float(np.mean([episode.episode_return for episode in episodes])),
            "validation_loss": validation_loss,
            "return": self.evaluate(self.policy) if self.evaluate is not None else float("nan"),
        }

    def _newest_frames(self, episode: Episode) -> Episode:
        """The episode as a round file holds it: of each stack of frames, the newest."""
        if not self.stacked_keys:
            return episode
        observations = episode.observations
        if isinstance(observations, dict):
            observations = {
                key: cast(np.ndarray, value)[:, -1] if key in self.stacked_keys else value
                for key, value in observations.items()
            }
        else:
            assert isinstance(observations, np.ndarray)
            observations = observations[:, -1]
        return dataclasses.replace(episode, observations=observations)

    def _fit(self, paths: Sequence[str | os.PathLike]) -> tuple[ActorCritic, float]:
        """BC on the aggregate dataset, warm-started from the current policy; the best validation loss."""
        dataset = DemoDataset(paths)
        bc = self.config.bc
        train_ids, validation_ids = split_episodes(
            len(dataset), validation_fraction=bc.validation_fraction, seed=self.config.seed
        )

        def load(episodes: list[int]) -> TransitionTensors:
            transitions = load_transitions(dataset, episodes=episodes, next_observations=False)
            if self.frames > 1:
                stacked = stack_frames(transitions.observations, transitions.episode_index, self.frames, self.stacked_keys)
                transitions = dataclasses.replace(transitions, observations=stacked)
            return transitions_to_torch(transitions)

        train = load(train_ids)
        validation = load(validation_ids) if validation_ids else None
        cloning = BehaviouralCloning(self.policy, train, validation, bc)
        losses = [row["validation_loss"] for row in fit(cloning) if np.isfinite(row["validation_loss"])]
        return cloning.policy, min(losses) if losses else float("nan")

    def state_dict(self) -> CheckpointData:
        """The learner, the mixture's generator, the label count and the finished rounds' files
        (by name: the run directory is renamed when it finishes)."""
        state = {
            "round": self.rounds + 1,
            "labels": self.labels,
            "rng": self.rng.bit_generator.state,
            "round_files": [path.name for path in self.files],
        }
        return prefixed("policy", self.policy.state_dict()), state

    def load_state_dict(self, checkpoint: CheckpointData) -> None:
        tensors, state = checkpoint
        with restoring("DAgger"):
            self.policy.load_state_dict(unprefixed("policy", tensors))
            self.rng.bit_generator.state = state["rng"]
            self.files = [self.round_dir / name for name in state["round_files"]]
            self.labels = int(state["labels"])
            self.rounds = checked_counter(int(state["round"]), "next round", 1, self.total + 1) - 1
        self.learner = SingleObservationPolicy(self.policy, deterministic=True)
