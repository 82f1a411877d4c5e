"""PPO's rollouts on Ray actors (docs/SCALING.md): the n_envs environment copies split over W workers.

Worker w steps copies [first_w, first_w + count_w) of the n_envs: it holds its own vector env
and a copy of π_k, and collects with exactly the code the single-process learner runs
(`PPO.collect_rollout` of a PPO over its own copies). Once per update the learner sends π_k's
weights to every worker (inside the call when small, else put once in Ray's object store, which
every worker reads), each worker loads them and collects n_steps steps, and the learner gathers
the W segments along the env axis into its own rollout buffers; `PPO.update` then runs as it does locally.

Copy i is reset with seed `seed + i` at the first rollout, as in the single-process run, so the
environments start from the same states; actions are sampled from each worker's own generator.
A flat policy's running observation statistics are folded in by the learner from all the
gathered observations at once, which gives what the local rollout's fold per step gives (pooled
moments); each worker's copy is overwritten at the next broadcast.

A worker that dies (its process killed, its node lost) is restarted by Ray and its collection
retried (`max_restarts`, `max_task_retries`): the restarted worker starts fresh episodes.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any

import numpy as np
import torch

from imitation.algorithms.ppo import PPO, PPOConfig
from imitation.errors import ImitationError
from imitation.ray_engine import RETRIES, ray_get, require_ray
from imitation.rewards import flat_batch, tree_index
from imitation.tensors import tree_map


def _numpy(tensor: torch.Tensor) -> np.ndarray:
    return tensor.detach().cpu().numpy()


class RolloutWorker:
    """One Ray actor's share of the environments: `count` copies starting at copy `first`,
    stepped by a CPU copy of the policy (`collect`)."""

    def __init__(self, config: PPOConfig, first: int, count: int, updates: int) -> None:
        torch.set_num_threads(1)
        share = dataclasses.replace(
            config,
            n_envs=count,
            total_steps=count * config.n_steps,
            # The first reset seeds copy i with `seed + i`: these copies get the seeds the
            # single-process run gives copies first..first+count after `updates` updates.
            seed=config.seed + updates * config.n_envs + first,
            device="cpu",
            threads=1,
        )
        self.learner = PPO(share)
        self.learner.folds_first_frames = updates == 0  # a resumed run's statistics hold them already

    def collect(self, weights: dict[str, np.ndarray]) -> dict[str, Any]:
        """n_steps steps of this worker's copies with π_k's `weights`: the rollout's tensors and
        the update's buffers as numpy arrays, the last observations, and finished episodes' returns."""
        started = time.perf_counter()
        # Ray hands over read-only views of its object store, which torch will not wrap: copy.
        self.learner.policy.load_state_dict({name: torch.from_numpy(np.array(value)) for name, value in weights.items()})
        loaded = time.perf_counter()
        self.learner.recent_returns.clear()
        rollout = self.learner.collect_rollout()
        buffers = self.learner.buffers
        # Views of the buffers, which the next collection refills: Ray serialises the return value
        # when this call ends, before the actor takes its next call.
        segment = {name: tree_map(_numpy, getattr(rollout, name)) for name in rollout.__dataclass_fields__}
        segment |= {
            "features": tree_map(_numpy, buffers.features),
            "values": _numpy(buffers.values),
            "truncated_values": _numpy(buffers.truncated_values),
            "parameters": _numpy(buffers.parameters),
            "last_observations": self.learner.observations,
            "returns": list(self.learner.recent_returns),
            "seconds_load": loaded - started,
            "seconds_collect": time.perf_counter() - loaded,
            "seconds_env": self.learner.timers["env"],
            "seconds_inference": self.learner.timers["inference"],
        }
        self.learner.timers = {name: 0.0 for name in self.learner.timers}
        return segment

    def close(self) -> None:
        self.learner.close()


# Weights up to this size travel inside each worker's call, as Ray inlines small arguments: a put
# would cost each worker a lookup of the object first (bench/RESULTS.md, issue 23). Larger ones
# (CNNs) are put once.
INLINE_BYTES = 100 * 1024


def split_copies(n_envs: int, workers: int) -> list[tuple[int, int]]:
    """(first, count) of each worker's copies: n_envs split as evenly as possible."""
    if not 1 <= workers <= n_envs:
        raise ImitationError(f"--workers {workers}: must be between 1 and the number of env copies ({n_envs})")
    base, extra = divmod(n_envs, workers)
    shares, first = [], 0
    for w in range(workers):
        count = base + (w < extra)
        shares.append((first, count))
        first += count
    return shares


class RayRollouts:
    """The learner's side: W `RolloutWorker` actors, one weight broadcast and one gather per rollout.

    `collect(learner)` fills `learner`'s rollout buffers in place, as `PPO.collect_rollout` does;
    `seconds` accumulates where the time went (the actors' start-up, broadcast, waiting on the
    workers, gathering)."""

    def __init__(self, n_envs: int, workers: int) -> None:
        self.shares = split_copies(n_envs, workers)
        self.ray = require_ray()
        self.workers: list[Any] = []
        self.seconds = {"start": 0.0, "broadcast": 0.0, "wait": 0.0, "gather": 0.0, "worker_collect": 0.0, "worker_load": 0.0}

    def _start(self, config: PPOConfig, updates: int) -> None:
        """The actors, started at the first rollout (a resumed learner has loaded its update count by
        then) and waited for, so that their start-up is counted once, as `seconds["start"]`, not in
        the first rollout's gather."""
        started = time.perf_counter()
        actor = self.ray.remote(num_cpus=1, max_restarts=RETRIES, max_task_retries=RETRIES)(RolloutWorker)
        self.workers = [actor.remote(config, first, count, updates) for first, count in self.shares]
        ray_get(self.ray, [worker.__ray_ready__.remote() for worker in self.workers])
        self.seconds["start"] = time.perf_counter() - started

    def collect(self, learner: PPO) -> None:
        ray = self.ray
        if not self.workers:
            self._start(learner.config, learner.updates)
        started = time.perf_counter()
        # As numpy arrays: Ray serialises them without copies, torch tensors through pickle, several
        # times slower to put and load (bench/RESULTS.md, issue 23).
        weights: Any = {name: tensor.detach().cpu().numpy() for name, tensor in learner.policy.state_dict().items()}
        if sum(array.nbytes for array in weights.values()) > INLINE_BYTES:
            weights = ray.put(weights)  # one copy in the object store, which every worker reads
        pending = [worker.collect.remote(weights) for worker in self.workers]
        broadcast = time.perf_counter()
        segments = ray_get(ray, pending)
        waited = time.perf_counter()
        self._gather(learner, segments)
        done = time.perf_counter()
        self.seconds["broadcast"] += broadcast - started
        self.seconds["wait"] += waited - broadcast
        self.seconds["gather"] += done - waited
        self.seconds["worker_collect"] += max(segment["seconds_collect"] for segment in segments)
        self.seconds["worker_load"] += max(segment["seconds_load"] for segment in segments)
        learner.timers["env"] += max(segment["seconds_env"] for segment in segments)
        learner.timers["inference"] += max(segment["seconds_inference"] for segment in segments)

    def _gather(self, learner: PPO, segments: list[dict[str, Any]]) -> None:
        rollout, buffers, device = learner.rollout_storage, learner.buffers, learner.device
        first_rollout = learner.observations is None and learner.updates == 0
        for (first, count), segment in zip(self.shares, segments):
            columns = slice(first, first + count)
            for name in rollout.__dataclass_fields__:
                _put(getattr(rollout, name), columns, segment[name], device)
            for name in ("values", "truncated_values", "parameters"):
                _put(getattr(buffers, name), columns, segment[name], device)
            if buffers.features is not None:
                _put(buffers.features, columns, segment["features"], device)
            learner.recent_returns.extend(segment["returns"])
        learner.observations = _concatenate([segment["last_observations"] for segment in segments])
        if learner.policy.layout is not None and first_rollout:
            # As the local learner folds the first frames in at its first reset (and each worker did).
            learner.policy.update_normalizer(tree_index(rollout.observations, 0))
        if learner.policy.layout is None:
            # One fold of the whole rollout: the same statistics as one per step (Chan et al.'s
            # pooled moments), at one call's cost.
            learner.policy.update_normalizer(flat_batch(rollout.observations, 2))

    def close(self) -> None:
        for worker in self.workers:
            self.ray.kill(worker)


def _put(target: Any, columns: slice, values: Any, device: torch.device) -> None:
    """target[:, columns] = values, leaf by leaf for a dict of observations."""
    if isinstance(target, dict):
        for key, leaf in target.items():
            _put(leaf, columns, values[key], device)
    elif target.device.type == "cpu":
        # Ray hands back read-only views of its object store: copy through numpy, which can read them.
        target[:, columns].numpy()[...] = values
    else:
        target[:, columns] = torch.as_tensor(np.array(values), device=device)


def _concatenate(observations: list[Any]) -> Any:
    if isinstance(observations[0], dict):
        return {key: np.concatenate([o[key] for o in observations]) for key in observations[0]}
    return np.concatenate(observations)
