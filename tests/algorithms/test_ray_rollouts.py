"""PPO's rollouts on Ray workers (imitation.algorithms.ray_rollouts): every buffer the update reads
arrives in the learner, in its env copy's column. One worker's rollout equals the local one tensor
for tensor; with two, each step's V(s_t), log π_k(a_t|s_t), π_k's parameters and the time-limit
bootstrap V(s_T) of a truncated episode are π_k's own, so π_k reached the workers and nothing
was dropped on the way back. Pendulum-v1's 200-step limit truncates every copy inside the first
256-step rollout. The workers run in this process (`RolloutWorker`, gathered by `RayRollouts`),
and on a real local Ray of 2 CPUs."""

from __future__ import annotations

import time

import numpy as np
import pytest
import torch

from imitation.algorithms.ppo import PPO, PPOConfig
from imitation.algorithms.ray_rollouts import INLINE_BYTES, RayRollouts, RolloutWorker, split_copies
from imitation.errors import ImitationError

pytest.importorskip("ray", reason="the Ray tests need the optional extra: pip install 'imitation-mcap[ray]'")

N_ENVS, N_STEPS = 4, 256


def config(**changes) -> PPOConfig:
    settings = dict(
        env_id="Pendulum-v1",
        total_steps=2 * N_ENVS * N_STEPS,
        n_envs=N_ENVS,
        n_steps=N_STEPS,
        batch_size=256,
        hidden_sizes=[8],
        seed=3,
        device="cpu",
    )
    return PPOConfig(**settings | changes)


def weights(learner: PPO) -> dict[str, np.ndarray]:
    return {name: tensor.detach().cpu().numpy() for name, tensor in learner.policy.state_dict().items()}


def gathered_in_this_process(settings: PPOConfig, workers: int) -> PPO:
    """A learner whose first rollout was collected by `workers` RolloutWorkers in this process and
    gathered as `RayRollouts.collect` gathers what Ray's workers return."""
    learner = PPO(settings)
    gatherer = RayRollouts(settings.n_envs, workers)
    sent = weights(learner)
    segments = []
    for first, count in gatherer.shares:
        worker = RolloutWorker(settings, first, count, learner.updates)
        segments.append(worker.collect(sent))
        worker.close()
    gatherer._gather(learner, segments)
    return learner


def buffers_of(learner: PPO) -> dict[str, torch.Tensor]:
    rollout, buffers = learner.rollout_storage, learner.buffers
    tensors = {name: getattr(rollout, name).clone() for name in rollout.__dataclass_fields__}
    for name in ("values", "truncated_values", "parameters", "features"):
        tensors[name] = getattr(buffers, name).clone()
    return tensors


def check_is_pi_k_own(learner: PPO) -> None:
    """Each step's stored V(s_t), log π(a_t|s_t) and parameters, and each truncated step's
    bootstrap value, recomputed from the learner's π_k (observations are not normalised here, so
    the features are the observations themselves)."""
    rollout, buffers, policy = learner.rollout_storage, learner.buffers, learner.policy
    truncated = rollout.truncated
    assert truncated.any(dim=0).all(), "every copy's episode is cut by the time limit"
    assert not rollout.terminated.any()
    with torch.no_grad():
        observations = rollout.observations.reshape(-1, 3)
        values = policy.value(observations).reshape(N_STEPS, N_ENVS)
        final_values = policy.value(rollout.next_observations.reshape(-1, 3)).reshape(N_STEPS, N_ENVS)
        parameters = policy.action_head(policy.actor_trunk(observations)).reshape(N_STEPS, N_ENVS, -1)
        log_probs = policy.log_prob(policy.distribution(observations), rollout.actions.reshape(-1, 1)).reshape(N_STEPS, N_ENVS)
    assert torch.equal(buffers.features, rollout.observations)
    torch.testing.assert_close(buffers.values, values, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(buffers.truncated_values, torch.where(truncated, final_values, 0.0), rtol=1e-5, atol=1e-6)
    assert (buffers.truncated_values[truncated] != 0).all()
    torch.testing.assert_close(buffers.parameters, parameters, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(rollout.log_probs, log_probs, rtol=1e-5, atol=1e-5)


def check_reset_states_and_counts(learner: PPO, local: dict[str, torch.Tensor]) -> None:
    """Copy i starts from seed + i, as in one process; the step count and the last observations."""
    assert torch.equal(learner.rollout_storage.observations[0], local["observations"][0])
    assert np.array_equal(learner.observations, learner.rollout_storage.next_observations[-1].numpy())
    assert len(learner.recent_returns) == N_ENVS  # each copy's one finished (truncated) episode


def local_rollout(settings: PPOConfig) -> tuple[dict[str, torch.Tensor], PPO]:
    learner = PPO(settings)
    learner.collect_rollout()
    return buffers_of(learner), learner


@pytest.mark.parametrize("normalize", [False, True])
def test_one_worker_fills_every_buffer_as_the_local_rollout_does(normalize: bool) -> None:
    settings = config(normalize_observations=normalize)
    local, local_learner = local_rollout(settings)
    learner = gathered_in_this_process(settings, 1)
    for name, tensor in buffers_of(learner).items():
        assert torch.equal(tensor, local[name]), name
    assert np.array_equal(learner.observations, local_learner.observations)
    assert list(learner.recent_returns) == list(local_learner.recent_returns)
    # The learner folds the whole rollout into its statistics at once: the per-step folds' moments.
    for name, tensor in local_learner.policy.state_dict().items():
        torch.testing.assert_close(learner.policy.state_dict()[name], tensor, rtol=1e-5, atol=1e-6, msg=name)
    local_learner.close()
    learner.close()


def test_two_workers_gather_pi_ks_values_and_bootstraps_into_their_copies_columns() -> None:
    settings = config()
    local, local_learner = local_rollout(settings)
    learner = gathered_in_this_process(settings, 2)
    check_is_pi_k_own(learner)
    check_reset_states_and_counts(learner, local)
    local_learner.close()
    learner.close()


def test_split_copies_keeps_order_and_gives_the_first_workers_the_extra_copies() -> None:
    assert split_copies(5, 2) == [(0, 3), (3, 2)]
    assert split_copies(3, 1) == [(0, 3)]


@pytest.mark.parametrize("hidden", [[8], [128, 128]], ids=["inline", "put"])
def test_two_ray_workers_return_pi_ks_values_and_bootstraps(hidden: list[int], local_ray) -> None:
    """Weights small enough travel inside the call, large ones through one put: either way the
    workers act with π_k and every buffer comes back."""
    settings = config(hidden_sizes=hidden)
    local, local_learner = local_rollout(settings)
    local_learner.close()
    remote = RayRollouts(N_ENVS, 2)
    learner = PPO(settings, remote=remote)
    try:
        size = sum(array.nbytes for array in weights(learner).values())
        assert (size > INLINE_BYTES) == (hidden != [8])
        learner.collect_rollout()
        check_is_pi_k_own(learner)
        check_reset_states_and_counts(learner, local)
        assert learner.global_step == N_ENVS * N_STEPS
        assert all(remote.seconds[name] > 0 for name in ("start", "broadcast", "wait", "gather", "worker_collect"))
        assert learner.timers["env"] > 0 and learner.timers["inference"] > 0
    finally:
        learner.close()
        remote.close()


def test_split_copies_gives_each_of_as_many_workers_as_copies_one_and_refuses_more_or_none() -> None:
    assert split_copies(4, 4) == [(0, 1), (1, 1), (2, 1), (3, 1)]
    for workers in (0, 5):
        refusal = rf"^--workers {workers}: must be between 1 and the number of env copies \(4\)$"
        with pytest.raises(ImitationError, match=refusal):
            split_copies(4, workers)


def test_a_gatherer_starts_with_no_time_counted_and_closes_before_any_rollout() -> None:
    """A run stopped before its first rollout closes a gatherer whose actors never started."""
    gatherer = RayRollouts(N_ENVS, 2)
    assert gatherer.seconds == dict.fromkeys(("start", "broadcast", "wait", "gather", "worker_collect", "worker_load"), 0.0)
    gatherer.close()
    assert gatherer.workers == []


def test_a_worker_is_a_one_thread_cpu_learner_whose_copies_start_where_the_single_process_run_puts_them() -> None:
    """Started on a learner that has made 3 updates (a resumed run), worker copies 1 and 2 are reset
    as the single-process learner resets its copies 1 and 2 at its fourth rollout, whatever device
    and threads the learner itself uses; its segment's timings lie within the call."""
    threads = torch.get_num_threads()
    local = PPO(config())
    local.updates = 3
    local.collect_rollout()
    try:
        worker = RolloutWorker(config(device="cuda", threads=2), 1, 2, 3)
        try:
            assert torch.get_num_threads() == 1 and worker.learner.device == torch.device("cpu")
            started = time.perf_counter()
            segment = worker.collect(weights(local))
            elapsed = time.perf_counter() - started
            timers = dict(worker.learner.timers)
        finally:
            worker.close()
    finally:
        local.close()
        torch.set_num_threads(threads)
    assert np.array_equal(segment["observations"][0], local.rollout_storage.observations[0, 1:3].numpy())
    assert segment["observations"].shape == (N_STEPS, 2, 3)
    assert segment["seconds_load"] > 0 and segment["seconds_collect"] > 0
    assert segment["seconds_load"] + segment["seconds_collect"] <= elapsed
    # The env's and the forward passes' time, measured inside the collection, is the worker's to report once.
    assert segment["seconds_env"] > 0 and segment["seconds_inference"] > 0
    assert segment["seconds_env"] + segment["seconds_inference"] <= segment["seconds_collect"]
    assert timers == {"env": 0.0, "inference": 0.0, "update": 0.0}


PIXELS = dict(
    env_id="CartPole-v1",
    pixels={"size": [36, 36], "grayscale": True},
    frame_stack=2,
    n_steps=8,
    total_steps=32,
    batch_size=8,
    cnn={"channels": [4], "kernels": [8], "strides": [4], "features": 16},
)


def test_dict_observations_gather_leaf_by_leaf_into_their_copies_columns() -> None:
    """Rendered frames beside the state: with one worker the rollout equals the local one leaf for
    leaf, and so do the policy's observation statistics (the first frames folded in, as the local
    learner does at its first reset); with two, each leaf's columns hold the segment of the worker
    that stepped those copies."""
    settings = config(**PIXELS, normalize_observations=True)
    local = PPO(settings)
    try:
        local.collect_rollout()
        alone = gathered_in_this_process(settings, 1)
        local_state, gathered_state = local.policy.state_dict(), alone.policy.state_dict()
        assert any(name.startswith("pixel_rms") for name in local_state)
        for name, tensor in local_state.items():
            assert torch.equal(gathered_state[name], tensor), name
        for name in local.rollout_storage.__dataclass_fields__:
            expected, gathered = getattr(local.rollout_storage, name), getattr(alone.rollout_storage, name)
            for key in expected if isinstance(expected, dict) else [None]:
                pair = (expected[key], gathered[key]) if key is not None else (expected, gathered)
                assert torch.equal(*pair), (name, key)
        assert alone.observations.keys() == local.observations.keys() == {"pixels", "state"}
        for key, leaf in local.observations.items():
            assert np.array_equal(alone.observations[key], leaf), key
        alone.close()
    finally:
        local.close()
    learner = PPO(settings)
    gatherer = RayRollouts(settings.n_envs, 2)
    segments = []
    for first, count in gatherer.shares:
        worker = RolloutWorker(settings, first, count, 0)
        segments.append(worker.collect(weights(learner)))
        worker.close()
    gatherer._gather(learner, segments)
    learner.close()
    for (first, count), segment in zip(gatherer.shares, segments):
        for name in ("observations", "next_observations"):
            for key in ("pixels", "state"):
                column = getattr(learner.rollout_storage, name)[key][:, first : first + count]
                assert np.array_equal(column.numpy(), segment[name][key]), (name, key, first)
    for key in ("pixels", "state"):
        assert np.array_equal(learner.observations[key], np.concatenate([s["last_observations"][key] for s in segments]))


def test_each_rollout_adds_its_time_and_a_killed_worker_is_restarted_and_its_collection_retried(local_ray) -> None:
    """The actors start once, each holding one CPU, and every later rollout adds its share of the
    time to the totals (set high here, so that a total replaced or taken from shows). A worker
    killed while it collects comes back, and the collection it was running is run again."""
    ray = local_ray
    settings = config(n_steps=2048, total_steps=4 * N_ENVS * 2048)
    remote = RayRollouts(N_ENVS, 2)
    learner = PPO(settings, remote=remote)
    try:
        started = time.perf_counter()
        learner.collect_rollout()
        assert 0 < remote.seconds["start"] < time.perf_counter() - started
        for worker in remote.workers:
            assigned = worker.__ray_call__.remote(lambda _: ray.get_runtime_context().get_assigned_resources())
            assert ray.get(assigned) == {"CPU": 1.0}
        remote.seconds = dict.fromkeys(remote.seconds, 1000.0)
        learner.timers = dict.fromkeys(learner.timers, 1000.0)
        started = time.perf_counter()
        learner.collect_rollout()
        elapsed = time.perf_counter() - started
        assert remote.seconds["start"] == 1000.0, "the actors started once"
        for name in ("broadcast", "wait", "gather", "worker_collect", "worker_load"):
            assert 1000.0 < remote.seconds[name] <= 1000.0 + elapsed, name
        for name in ("env", "inference"):
            assert 1000.0 < learner.timers[name] <= 1000.0 + elapsed, name
        victim = remote.workers[0]
        pending = victim.collect.remote(weights(learner))
        time.sleep(0.2)  # well inside its 4,096 steps
        ray.kill(victim, no_restart=False)
        segment = ray.get(pending)
        assert segment["observations"].shape == (2048, 2, 3) and len(segment["returns"]) >= 2
    finally:
        learner.close()
        remote.close()


def test_a_resumed_image_learner_leaves_the_first_frames_out_of_its_statistics_as_the_local_one_does() -> None:
    """Restored from a checkpoint taken after an update, the local learner resets its envs without
    folding the first frames into its image statistics (they were counted in the run's first
    rollout): the gathered rollout leaves the restored statistics as they are too, and the worker
    acts with them, not with a copy that folded the first frames at its own first reset."""
    settings = config(**PIXELS | {"total_steps": 64}, normalize_observations=True)
    source = PPO(settings)
    source.updates = 1
    checkpoint = source.state_dict()
    source.close()
    local, gathered = PPO(settings), PPO(settings)
    try:
        for learner in (local, gathered):
            learner.load_state_dict(checkpoint)
        restored = {name: tensor.clone() for name, tensor in gathered.policy.state_dict().items()}
        local.collect_rollout()
        gatherer = RayRollouts(settings.n_envs, 1)
        worker = RolloutWorker(settings, 0, settings.n_envs, gathered.updates)
        try:
            segment = worker.collect(weights(gathered))
        finally:
            worker.close()
        gatherer._gather(gathered, [segment])
        assert torch.equal(gathered.rollout_storage.observations["pixels"][0], local.rollout_storage.observations["pixels"][0])
        statistics = [name for name in restored if name.startswith(("pixel_rms", "obs_rms"))]
        assert any(name.startswith("pixel_rms") for name in statistics)
        for name in statistics:
            assert torch.equal(local.policy.state_dict()[name], restored[name]), name
            assert torch.equal(gathered.policy.state_dict()[name], restored[name]), name
        # The first step sees the same frames through the same statistics: the same V and π's
        # parameters (the steps after it follow the worker's own sampling, not the restored one's).
        for name in ("values", "parameters"):
            assert torch.equal(getattr(gathered.buffers, name)[0], getattr(local.buffers, name)[0]), name
    finally:
        local.close()
        gathered.close()
