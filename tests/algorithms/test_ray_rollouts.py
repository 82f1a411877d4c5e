"""PPO's rollouts on Ray workers (imitation.algorithms.ray_rollouts): every buffer the update reads
arrives in the learner, in its env copy's column. One worker's rollout equals the local one tensor
for tensor; with two, each step's V(s_t), log π_k(a_t|s_t), π_k's parameters and the time-limit
bootstrap V(s_T) of a truncated episode are π_k's own, so π_k reached the workers and nothing
was dropped on the way back. Pendulum-v1's 200-step limit truncates every copy inside the first
256-step rollout. The workers run in this process (`RolloutWorker`, gathered by `RayRollouts`),
and on a real local Ray of 2 CPUs."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from imitation.algorithms.ppo import PPO, PPOConfig
from imitation.algorithms.ray_rollouts import INLINE_BYTES, RayRollouts, RolloutWorker, split_copies

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
