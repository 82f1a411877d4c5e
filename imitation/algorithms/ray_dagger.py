"""DAgger's rounds on Ray workers (docs/SCALING.md): each worker plays its share of a round's episodes
and writes them to its own MCAP shard, round-NN-wK.mcap; the round's data is the union of the
shards, and BC trains on the demos and every shard so far.

Worker k of W plays episodes k, k + W, k + 2W, … of the round (reset with the seeds the
single-process round gives them), with its own env and expert built by `make`, π̂_i sent once per
round, and the β-mixture's draws from a generator seeded by (seed, round, k). Each episode is
flushed to the shard as it ends (`play_round`). A worker process that dies mid-round is restarted
by Ray and its collection retried: the retry keeps the episodes the shard already holds, and
plays only the rest.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch

from imitation.algorithms.dagger import Policy, play_round
from imitation.policies import SingleObservationPolicy
from imitation.policy_protocol import ImitationPolicy
from imitation.ray_engine import RETRIES, ray_get, require_ray

EnvAndExpert = Callable[[], tuple[gym.Env, Policy]]


class RoundWorker:
    """One Ray actor: an env and an expert (built once by `make`) playing episodes into its shards."""

    def __init__(self, make: EnvAndExpert) -> None:
        torch.set_num_threads(1)
        self.env, self.expert = make()

    def collect(
        self,
        policy: ImitationPolicy | None,
        path: str,
        *,
        env_id: str,
        round_index: int,
        beta: float,
        mode: str,
        seeds: list[int],
        rng_seed: list[int],
        metadata: dict[str, Any],
    ) -> int:
        """The episodes reset with `seeds` played into the shard `path`; how many it holds."""
        learner = SingleObservationPolicy(policy, deterministic=True) if policy is not None else None
        episodes = play_round(
            self.env,
            learner,
            self.expert,
            Path(path),
            env_id=env_id,
            round_index=round_index,
            beta=beta,
            mode=mode,
            seeds=seeds,
            rng=np.random.default_rng(rng_seed),
            metadata=metadata,
        )
        return len(episodes)

    def close(self) -> None:
        self.env.close()


class RayRounds:
    """The learner's side: `workers` `RoundWorker` actors, one shard each per round."""

    def __init__(
        self, workers: int, make: EnvAndExpert, *, round_dir: Path, env_id: str, mode: str, seed: int, metadata: dict[str, Any]
    ) -> None:
        self.ray = ray = require_ray()
        actor = ray.remote(num_cpus=1, max_restarts=RETRIES, max_task_retries=RETRIES)(RoundWorker)
        self.workers = [actor.remote(make) for _ in range(workers)]
        self.round_dir, self.env_id, self.mode, self.seed = round_dir, env_id, mode, seed
        self.metadata = {**metadata, "mode": mode}

    def collect(self, policy: ImitationPolicy | None, round_index: int, beta: float, seeds: list[int]) -> list[Path]:
        """The round's shards, written by the workers; a worker with no episode to play writes none."""
        sent = self.ray.put(copy.deepcopy(policy).cpu() if policy is not None else None)
        shards, pending = [], []
        for k, worker in enumerate(self.workers):
            share = seeds[k :: len(self.workers)]
            if not share:
                continue
            path = self.round_dir / f"round-{round_index:02d}-w{k}.mcap"
            shards.append(path)
            pending.append(
                worker.collect.remote(
                    sent,
                    str(path),
                    env_id=self.env_id,
                    round_index=round_index,
                    beta=beta,
                    mode=self.mode,
                    seeds=share,
                    rng_seed=[self.seed, round_index, k],
                    metadata={**self.metadata, "worker": k},
                )
            )
        ray_get(self.ray, pending)
        return shards

    def close(self) -> None:
        for worker in self.workers:
            self.ray.kill(worker)
