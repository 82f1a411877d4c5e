"""DAgger, dataset aggregation (docs/THEORY.md §5.2; Ross, Gordon & Bagnell 2011).

    D ← expert demos (optional);  π̂_1 ← BC(D)
    for i = 1 … R:
        π_i = β_i π* + (1 - β_i) π̂_i          at each step the expert acts with probability β_i
        run π_i; label every visited state s with the expert's action π*(s)  →  D_i
        D ← D ∪ D_i;  π̂_{i+1} ← BC(D)

β schedules: linear β_i = max(0, 1 - (i-1)/R), exponential β_i = p^(i-1). Without demos round 1
is the expert's alone (β_1 = 1) and its rollouts are the first expert data. Demos are that data
already, so with them round i runs at β_{i+1}: round 1 lets π̂_1 drive instead of spending labels
on the expert's own path a second time. The learner visits its own state distribution and the
expert says what it should have done there, which is what removes BC's compounding error (the
notes' O(εT²) → O(εT)).

Take-over mode (HG-DAgger, Kelly et al. 2019; docs/THEORY.md §5.2), for an expert that can
take the controls (a person, `imitation.experts.standin.StandIn`):

    a_t = π*(s_t) while the expert is engaged, else π̂_i(s_t);   D_i = {(s_t, π*(s_t)) : the expert drove t}

Round 1 already has a learner to correct (the untrained policy, or BC on the demos). With
`label="all"` the steps the learner drove join D_i with its own actions as labels.

Each round's rollouts are written, episode by episode, as an MCAP demo file (round-NN.mcap)
whose actions are the expert's labels (take-over: the executed actions) and whose intervention
channels record who drove each step, the learner's proposed and the executed action, with
wall-clock times (docs/FORMAT.md §6.7); the episodes' metadata record the round, β and how many
steps the expert drove. A round stopped midway (Ctrl-C twice, Esc in a person's window, a kill)
keeps its finished episodes; the resumed run keeps them and plays the rest of the round.

With pixel observations the learner acts on stacks of frames (`StackFrames`) while a round file
holds single frames, the newest of each stack, and BC restacks them (`stack_frames`): what the
learner trains on is exactly what it saw.

The state saved after a round is the learner, the β-mixture's generator, the label count and
the finished rounds' file names; a resumed run goes on with the next round (from its finished
episodes, with the mixture's draws they took skipped) and trains on the finished rounds' files
as they are. Each round's BC starts afresh from
its seed (a new optimiser, the normaliser refitted), and rollouts are reset with seeds fixed by
the round, so the resumed run ends exactly where an uninterrupted one does, as long as the
expert is deterministic (`random` and tabular soft-optimal experts restart their generators).
"""

from __future__ import annotations

import dataclasses
import os
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Protocol, cast

import gymnasium as gym
import numpy as np

from imitation.algorithms.bc import BehaviouralCloning, fit
from imitation.algorithms.dagger_config import DAggerConfig
from imitation.checkpoints import CheckpointData, CheckpointReader, CheckpointWriter
from imitation.data.dataset import DemoDataset
from imitation.data.loader import (
    TransitionTensors,
    load_transitions,
    select_human_steps,
    split_episodes,
    transitions_to_torch,
)
from imitation.data.mcap.reader import DemoFile
from imitation.data.mcap.writer import DemoWriter
from imitation.data.recover import PARTIAL_SUFFIX, recover_partial
from imitation.data.types import Episode, Interventions, stack_samples
from imitation.envs.make import control_period
from imitation.envs.pixels import StackFrames, stack_frames
from imitation.envs.rollout import start_episode
from imitation.policies import SingleObservationPolicy
from imitation.policy_protocol import ImitationPolicy


class TakesOver(Protocol):
    """An expert that can take the controls (`--mode takeover`): after each call, `engaged` says
    whether it holds them (a person at the keyboard, gamepad or mouse, or `StandIn`)."""

    engaged: bool

    def __call__(self, observation: Any) -> Any: ...


Policy = Callable[[Any], Any]


def beta_for_round(round_index: int, config: DAggerConfig) -> float:
    """β_i for round i = 1 … R."""
    if config.beta_schedule == "linear":
        return max(0.0, 1.0 - (round_index - 1) / config.rounds)
    return config.beta_decay ** (round_index - 1)


def run_episode(
    env: gym.Env,
    learner: Policy | None,
    expert: Policy,
    *,
    mode: str = "label",
    beta: float = 1.0,
    seed: int,
    rng: np.random.Generator,
    metadata: dict[str, Any],
    status: Callable[[int, bool, int], None] | None = None,
) -> Episode:
    """One episode of expert and learner sharing the controls (see `DAggerConfig.mode`); the
    episode records, step by step, who drove, what the learner proposed and what was executed,
    with wall-clock timestamps. `status(step, human_in_control, takeovers)` is called before the
    expert is asked at each step (a person's window shows it)."""
    observation, _ = env.reset(seed=seed)
    start_episode(learner)
    observations, times = [observation], [time.time_ns()]
    actions: list[Any] = []
    proposed: list[Any] = []
    executed: list[Any] = []
    rewards: list[float] = []
    human: list[bool] = []
    terminated = truncated = False
    takeovers = 0
    while not (terminated or truncated):
        driving = bool(human[-1]) if human else False  # the learner holds the controls before step 0
        if status is not None:
            status(len(actions), driving, takeovers)
        label = expert(observation)
        learner_action = learner(observation) if learner is not None else label
        if mode == "takeover":
            person_drives = learner is None or cast(TakesOver, expert).engaged
        else:
            person_drives = learner is None or rng.random() < beta
        action = label if person_drives else learner_action
        takeovers += int(person_drives and not driving)
        observation, reward, terminated, truncated, _ = env.step(action)
        times.append(time.time_ns())
        observations.append(observation)
        # Labelling: the expert's command at every state. Take-over: what was executed; the
        # steps the learner drove are told apart by `human` (the person let them pass).
        actions.append(action if mode == "takeover" else label)
        rewards.append(float(reward))
        human.append(person_drives)
        proposed.append(learner_action)
        executed.append(action)
    return Episode(
        observations=stack_samples(observations, env.observation_space),
        actions=stack_samples(actions, env.action_space),
        rewards=np.asarray(rewards),
        terminated=bool(terminated),
        truncated=bool(truncated) and not terminated,
        timestamps=np.asarray(times, dtype=np.int64),
        interventions=Interventions(
            human=np.asarray(human, dtype=bool),
            proposed_actions=stack_samples(proposed, env.action_space),
            executed_actions=stack_samples(executed, env.action_space),
        ),
        metadata={**metadata, "seed": seed, "expert_steps": int(sum(human))},
    )


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
    mode: str = "label",
) -> list[Episode]:
    """`episodes` episodes of `run_episode`, episode i reset with seed `seed + i`."""
    return [
        run_episode(env, learner, expert, mode=mode, beta=beta, seed=seed + i, rng=rng, metadata=metadata)
        for i in range(episodes)
    ]


def finished_episodes(path: Path) -> list[Episode]:
    """The episodes an interrupted try of a round finished: those of `path` (closed on Ctrl-C)
    or of `path`.partial (left by a killed process), whichever holds more. A partial with more
    is recovered into `path` first; it begins with `path`'s episodes, so dropping `path` before
    that loses nothing even if this run is killed too."""
    partial = path.with_name(path.name + PARTIAL_SUFFIX)
    if partial.exists():
        if len(DemoFile(partial, salvage=True)) > (len(DemoFile(path)) if path.exists() else 0):
            path.unlink(missing_ok=True)
            recover_partial(partial, path)
        else:
            partial.unlink()
    return DemoFile(path).read_episodes() if path.exists() else []


def round_writer(
    path: Path, env: gym.Env, *, env_id: str, round_index: int, beta: float, metadata: dict[str, Any]
) -> DemoWriter:
    """A round's file (round-NN.mcap, or a worker's shard of it); each episode is flushed as it
    ends, so a killed run keeps it. A StackFrames env's file holds single frames."""
    return DemoWriter(
        path,
        env_id=env_id,
        observation_space=env.env.observation_space if isinstance(env, StackFrames) else env.observation_space,
        action_space=env.action_space,
        dt=control_period(env),
        source=f"dagger round {round_index}",
        metadata={**metadata, "round": round_index, "beta": beta},
        flush_episodes=True,
    )


def newest_frames(episode: Episode, env: gym.Env) -> Episode:
    """The episode as a round file holds it: of each stack of frames (a StackFrames env), the newest."""
    if not isinstance(env, StackFrames):
        return episode
    observations = episode.observations
    if isinstance(observations, dict):
        observations = {
            key: cast(np.ndarray, value)[:, -1] if key in env.keys else value for key, value in observations.items()
        }
    else:
        assert isinstance(observations, np.ndarray)
        observations = observations[:, -1]
    return dataclasses.replace(episode, observations=observations)


def play_round(
    env: gym.Env,
    learner: Policy | None,
    expert: Policy,
    path: Path,
    *,
    env_id: str,
    round_index: int,
    beta: float,
    mode: str,
    seeds: Sequence[int],
    rng: np.random.Generator,
    metadata: dict[str, Any],
    status: Callable[[int, list[Episode]], Callable[[int, bool, int], None] | None] | None = None,
) -> list[Episode]:
    """The episodes reset with `seeds`, played by the β-mixture (`run_episode`) into the file
    `path`, continuing an interrupted try of it: the episodes that try finished are kept, and
    the mixture's draws they took skipped, so the file ends as an uninterrupted try's would.
    `status(episode number, finished)` gives the status callback of each episode's steps."""
    episodes = finished_episodes(path)
    if episodes and learner is not None and mode == "label":
        rng.random(sum(len(episode) for episode in episodes))  # the draws they took, as if uninterrupted
    with round_writer(path, env, env_id=env_id, round_index=round_index, beta=beta, metadata=metadata) as writer:
        for episode in episodes:
            writer.write(episode)
        for i in range(len(episodes), len(seeds)):
            episode = run_episode(
                env,
                learner,
                expert,
                mode=mode,
                beta=beta,
                seed=seeds[i],
                rng=rng,
                metadata={"round": round_index, "beta": beta},
                status=status(i + 1, episodes) if status is not None else None,
            )
            episodes.append(newest_frames(episode, env))
            writer.write(episodes[-1])
    return episodes


class RemoteRounds(Protocol):
    """A round's episodes played elsewhere (Ray workers: `imitation.algorithms.ray_dagger`), each
    worker writing its own shard; `collect` returns the shards' paths."""

    def collect(self, policy: ImitationPolicy | None, round_index: int, beta: float, seeds: list[int]) -> list[Path]: ...

    def close(self) -> None: ...


class DAgger:
    """The learner: one round per step (roll out the β-mixture, write the round's labelled
    episodes to `round_dir`, retrain BC on the demos and every round so far)."""

    name = "DAgger"
    unit = "round"

    def __init__(
        self,
        env: gym.Env,
        expert: Policy,
        policy: ImitationPolicy,
        config: DAggerConfig,
        *,
        round_dir: str | os.PathLike,
        env_id: str,
        demos: Sequence[str | os.PathLike] = (),
        evaluate: Callable[[ImitationPolicy], float] | None = None,
        metadata: dict[str, Any] | None = None,
        remote: RemoteRounds | None = None,
    ) -> None:
        config.validate()
        self.env, self.expert, self.policy, self.config = env, expert, policy, config
        self.remote = remote
        # A StackFrames env's observations are stacks; the round files hold their newest frames.
        self.stacked_keys = env.keys if isinstance(env, StackFrames) else []
        self.frames = env.frames if isinstance(env, StackFrames) else 1
        self.metadata = {**(metadata or {}), "mode": config.mode}
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
        elif self.learner is None and self.config.mode == "takeover":
            self.learner = SingleObservationPolicy(self.policy, deterministic=True)  # the person corrects it from the start
        round_index = self.rounds + 1
        beta = beta_for_round(round_index + 1 if self.demos else round_index, self.config)
        first_seed = self.config.seed * 100_000 + round_index * 1_000
        seeds = list(range(first_seed, first_seed + self.config.episodes_per_round))
        if self.remote is not None:
            shards = self.remote.collect(self.policy if self.learner is not None else None, round_index, beta, seeds)
            episodes = [episode for shard in shards for episode in DemoFile(shard).read_episodes()]
            self.files += shards
        else:
            path = self.round_dir / f"round-{round_index:02d}.mcap"
            episodes = play_round(
                self.env,
                self.learner,
                self.expert,
                path,
                env_id=self.env_id,
                round_index=round_index,
                beta=beta,
                mode=self.config.mode,
                seeds=seeds,
                rng=self.rng,
                metadata=self.metadata,
                status=lambda number, finished: self._status(round_index, number, finished),
            )
            self.files.append(path)
        self.labels += int(sum(self._labels(episode).sum() for episode in episodes))
        self.policy, validation_loss = self._fit([*self.demos, *self.files])
        self.learner = SingleObservationPolicy(self.policy, deterministic=True)
        self.rounds = round_index
        steps = sum(len(episode) for episode in episodes)
        return {
            "round": float(round_index),
            "beta": beta,
            "expert_labels": float(self.labels),
            "rollout_return": float(np.mean([episode.episode_return for episode in episodes])),
            "intervention_rate": sum(self._human(episode).sum() for episode in episodes) / max(1, steps),
            "takeovers": float(sum(self._takeovers(episode) for episode in episodes)),
            "validation_loss": validation_loss,
            "return": self.evaluate(self.policy) if self.evaluate is not None else float("nan"),
        }

    def _status(
        self, round_index: int, episode_number: int, finished: list[Episode]
    ) -> Callable[[int, bool, int], None] | None:
        """What a person's window shows before each step, for an expert that has one."""
        show = getattr(self.expert, "show_status", None)
        if show is None:
            return None
        from imitation.experts.window import ControlStatus  # pygame's window only for a person

        before = sum(self._takeovers(episode) for episode in finished)

        def status(step: int, human_in_control: bool, takeovers: int) -> None:
            show(ControlStatus(round_index, episode_number, step, human_in_control, before + takeovers, self.config.mode))

        return status

    @staticmethod
    def _human(episode: Episode) -> np.ndarray:
        return episode.interventions.human if episode.interventions is not None else np.ones(len(episode), dtype=bool)

    @staticmethod
    def _takeovers(episode: Episode) -> int:
        return episode.interventions.takeovers if episode.interventions is not None else 0

    def _labels(self, episode: Episode) -> np.ndarray:
        """Which of a round episode's steps BC trains on: all of them, except in take-over
        mode with `label="human"`, where only those the expert drove."""
        if self.config.mode == "takeover" and self.config.label == "human":
            return self._human(episode)
        return np.ones(len(episode), dtype=bool)

    def _fit(self, paths: Sequence[str | os.PathLike]) -> tuple[ImitationPolicy, float]:
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
        if self.config.mode == "takeover" and self.config.label == "human":  # the expert's steps; demos are all theirs
            train = select_human_steps(train, dataset, train_ids, unrecorded=True)
            if validation is not None:
                validation = select_human_steps(validation, dataset, validation_ids, unrecorded=True)
            if validation is not None and len(validation) == 0:
                validation = None
            if len(train) == 0:  # the expert has not taken over yet: nothing to learn from
                return self.policy, float("nan")
        cloning = BehaviouralCloning(self.policy, train, validation, bc)
        losses = [row["validation_loss"] for row in fit(cloning) if np.isfinite(row["validation_loss"])]
        return cloning.policy, min(losses) if losses else float("nan")

    def state_dict(self) -> CheckpointData:
        """The learner, the mixture's generator, the label count and the finished rounds' files
        (by name: the run directory is renamed when it finishes)."""
        checkpoint = CheckpointWriter(
            round=self.rounds + 1,
            labels=self.labels,
            rng=self.rng.bit_generator.state,
            round_files=[path.name for path in self.files],
        )
        checkpoint.module("policy", self.policy.state_dict())
        return checkpoint.data()

    def load_state_dict(self, checkpoint: CheckpointData) -> None:
        with CheckpointReader(checkpoint, "DAgger") as saved:
            self.policy.load_state_dict(saved.module("policy"))
            self.rng.bit_generator.state = saved.state["rng"]
            self.files = [self.round_dir / name for name in saved.state["round_files"]]
            self.labels = int(saved.state["labels"])
            self.rounds = saved.counter("round", "next round", 1, self.total + 1) - 1
        self.learner = SingleObservationPolicy(self.policy, deterministic=True)
