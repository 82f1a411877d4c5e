"""DAgger's rounds on Ray workers (imitation.algorithms.ray_dagger), step by step: worker k plays
seeds k, k + W, … of the round with the learner it was sent, and its β-mixture draws come from
its own generator seeded (seed, round, k). Every step's driver, proposal and label is checked
against that generator and the two policies, for a worker in this process (`RoundWorker`) and for
the learner's side on a real local Ray of 2 CPUs (`RayRounds`)."""

from __future__ import annotations

import functools
import os
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch

from imitation.algorithms.ray_dagger import RayRounds, RoundWorker
from imitation.data.mcap.reader import DemoFile
from imitation.jobs.dagger import env_and_expert
from imitation.policies import ActorCritic, SingleObservationPolicy, make_policy

ENV_ID = "CartPole-v1"
SEED = 7
ROUND = 3
# Far from ½, so that drawing with 1 − β instead shows in the share of steps the expert drove.
BETA = 0.8
MAKE = functools.partial(env_and_expert, ENV_ID, "scripted", None, 1, seed=SEED)
METADATA = {"mode": "label", "note": "ray dagger test"}


def learner() -> ActorCritic:
    """A policy of fixed random weights: it pushes the cart the other way from the scripted
    expert on many states, so the steps it drove show in the actions executed."""
    torch.manual_seed(0)
    env = gym.make(ENV_ID)
    return make_policy(env.observation_space, env.action_space, hidden_sizes=[8])


def check_shard(
    path: Path, policy: ActorCritic | None, k: int, seeds: list[int], *, round_index: int = ROUND, metadata: dict = METADATA
) -> int:
    """The shard of worker k against its generator and both policies, step by step; its step count."""
    shard = DemoFile(path)
    assert [facts.metadata["seed"] for facts in shard.episodes] == seeds
    assert shard.user_metadata == {**metadata, "round": round_index, "beta": BETA}
    _, expert = MAKE()
    acting = SingleObservationPolicy(policy, deterministic=True) if policy is not None else None
    draws = np.random.default_rng([SEED, round_index, k])
    steps = 0
    for episode in shard.read_episodes():
        assert episode.metadata["round"] == round_index and episode.metadata["beta"] == BETA
        for t in range(len(episode)):
            observation = np.array(episode.observations[t])  # a writable copy of the file's view
            label = expert(observation)
            proposed = acting(observation) if acting is not None else label
            drives = acting is None or draws.random() < BETA
            assert episode.actions[t] == label, (k, t)
            assert episode.interventions.human[t] == drives, (k, t)
            assert episode.interventions.proposed_actions[t] == proposed, (k, t)
            assert episode.interventions.executed_actions[t] == (label if drives else proposed), (k, t)
        steps += len(episode)
    return steps


def test_a_worker_plays_its_seeds_with_the_learner_it_was_sent_and_its_own_draws(tmp_path: Path) -> None:
    """`RoundWorker` in this process: two workers' shards of one round, each drawn from its own
    generator; the learner, not the expert alone, drives about 1 − β of the steps."""
    policy = learner()
    seeds = [100, 101, 102, 103]
    worker = RoundWorker(MAKE)
    driven_by_learner = total = 0
    for k in range(2):
        path = tmp_path / f"round-{ROUND:02d}-w{k}.mcap"
        count = worker.collect(
            policy,
            str(path),
            env_id=ENV_ID,
            round_index=ROUND,
            beta=BETA,
            mode="label",
            seeds=seeds[k::2],
            rng_seed=[SEED, ROUND, k],
            metadata=METADATA,
        )
        assert count == 2
        total += check_shard(path, policy, k, seeds[k::2])
        human = np.concatenate([episode.interventions.human for episode in DemoFile(path).read_episodes()])
        driven_by_learner += int((~human).sum())
    worker.close()
    assert 0.1 < driven_by_learner / total < 0.35


def test_a_worker_sent_no_learner_lets_the_expert_drive_every_step(tmp_path: Path) -> None:
    path = tmp_path / "round-01-w0.mcap"
    worker = RoundWorker(MAKE)
    worker.collect(
        None,
        str(path),
        env_id=ENV_ID,
        round_index=ROUND,
        beta=BETA,
        mode="label",
        seeds=[5],
        rng_seed=[SEED, ROUND, 0],
        metadata=METADATA,
    )
    worker.close()
    check_shard(path, None, 0, [5])


def test_a_retried_shard_keeps_its_finished_episodes_and_draws_on_as_if_uninterrupted(tmp_path: Path) -> None:
    """A worker's first try finished one episode of three (Ray then retries the collection): the
    retry keeps that episode, skips the draws it took, and plays the rest from the same stream."""
    policy = learner()
    seeds = [300, 301, 302]
    worker = RoundWorker(MAKE)
    path = tmp_path / f"round-{ROUND:02d}-w1.mcap"
    options = dict(env_id=ENV_ID, round_index=ROUND, beta=BETA, mode="label", rng_seed=[SEED, ROUND, 1], metadata=METADATA)
    assert worker.collect(policy, str(path), seeds=seeds[:1], **options) == 1
    first = DemoFile(path).read_episodes()[0]
    assert worker.collect(policy, str(path), seeds=seeds, **options) == 3
    worker.close()
    check_shard(path, policy, 1, seeds)
    kept = DemoFile(path).read_episodes()[0]
    assert np.array_equal(kept.timestamps, first.timestamps)  # the episode itself, not a replay of it


def test_a_worker_runs_torch_on_one_thread() -> None:
    """Each Ray worker takes one CPU (`num_cpus=1`): its torch must not spread over more."""
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        RoundWorker(MAKE).close()
        assert torch.get_num_threads() == 1
    finally:
        torch.set_num_threads(before)


ray = pytest.importorskip("ray", reason="the Ray tests need the optional extra: pip install 'imitation-mcap[ray]'")


def test_the_round_on_two_ray_workers_is_each_workers_seeds_learner_and_draws(tmp_path: Path, local_ray) -> None:
    """`RayRounds`: π̂_i reaches both workers, each shard is its worker's seeds and its own draws
    (seeded with the worker's index), with β as given; a round without a learner is the expert's."""
    policy = learner()
    seeds = [200, 201, 202, 203, 204]
    rounds = RayRounds(
        2, MAKE, round_dir=tmp_path, env_id=ENV_ID, mode="label", seed=SEED, metadata={"note": METADATA["note"]}
    )
    try:
        shards = rounds.collect(policy, ROUND, BETA, seeds)
        assert [path.name for path in shards] == [f"round-{ROUND:02d}-w0.mcap", f"round-{ROUND:02d}-w1.mcap"]
        for k, path in enumerate(shards):
            check_shard(path, policy, k, seeds[k::2], metadata=METADATA | {"worker": k})
        expert_round = rounds.collect(None, ROUND + 1, BETA, seeds[:1])
        assert len(expert_round) == 1  # worker 1 had no seed to play: no shard
        check_shard(expert_round[0], None, 0, seeds[:1], round_index=ROUND + 1, metadata=METADATA | {"worker": 0})
        assert local_ray.available_resources().get("CPU", 0) == 0  # each worker holds one of the 2 CPUs
    finally:
        rounds.close()


class DiesOnce(gym.Wrapper):
    """Ends its process (as a killed worker's ends) on the reset with `seed`, the first time only:
    `marker` records that it happened."""

    def __init__(self, env: gym.Env, marker: str, seed: int) -> None:
        super().__init__(env)
        self.marker, self.seed = Path(marker), seed

    def reset(self, *, seed=None, options=None):
        if seed == self.seed and not self.marker.exists():
            self.marker.touch()
            os._exit(1)
        return self.env.reset(seed=seed, options=options)


def dies_once(marker: str, seed: int):
    env, expert = MAKE()
    return DiesOnce(env, marker, seed), expert


def test_a_worker_that_dies_mid_round_is_restarted_and_its_shard_finished_as_if_uninterrupted(
    tmp_path: Path, local_ray
) -> None:
    """Worker 1's process ends as its second episode starts: Ray restarts it and reruns its
    collection, which keeps the episode the shard holds and plays the rest with the same draws."""
    local_ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])  # the workers cannot import this file
    policy = learner()
    seeds = [400, 401, 402, 403]
    marker = tmp_path / "died"
    rounds = RayRounds(
        2,
        functools.partial(dies_once, str(marker), seeds[3]),
        round_dir=tmp_path,
        env_id=ENV_ID,
        mode="label",
        seed=SEED,
        metadata={"note": METADATA["note"]},
    )
    try:
        shards = rounds.collect(policy, ROUND, BETA, seeds)
        assert marker.exists()
        for k, path in enumerate(shards):
            check_shard(path, policy, k, seeds[k::2], metadata=METADATA | {"worker": k})
    finally:
        rounds.close()
