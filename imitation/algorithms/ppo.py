"""Proximal policy optimisation (docs/THEORY.md §4), readable top to bottom like CleanRL's ppo.py.

Each update collects n_steps × n_envs transitions with the current policy π_k
(`PPO.collect_rollout`), then takes n_epochs passes of minibatch gradient steps on one of two
objectives (`PPO.update`, `ppo_update`):

- clipped surrogate:  L^CLIP(θ) = E[ min( r_t(θ) Â_t, clip(r_t(θ), 1-ε, 1+ε) Â_t ) ],
  r_t(θ) = π_θ(a_t|s_t) / π_k(a_t|s_t)
- adaptive KL penalty: L^KL(θ) = E[ r_t(θ) Â_t ] - β · E_s[ D_KL(π_k(·|s) || π_θ(·|s)) ],
  after each update β ← 2β if D̄_KL ≥ 1.5 δ, β ← β/2 if D̄_KL ≤ δ/1.5 (target δ)

with advantages from truncated GAE(γ, λ) (`imitation.algorithms.advantages`):

    δ_t = r_t + γ (1 - term_t) V(s_{t+1}) - V(s_t)
    Â_t = δ_t + γ λ (1 - done_t) Â_{t+1}

where done_t = term_t or trunc_t. On truncation (time limit) s_{t+1} is the true final state of
the episode and V(s_{t+1}) is bootstrapped; on termination it is not. The critic regresses on
R_t = Â_t + V(s_t). The loss minimised is -L + c_v · (V - R)² / 2 - c_H · H[π].

The implementation details (CleanRL's "37 details") each appear as a visible line: vectorised
envs, orthogonal init (in imitation.policies), Adam eps 1e-5, learning-rate annealing,
minibatch advantage normalisation, optional value clipping, entropy bonus, global gradient
clipping, optional KL early stop, running observation normalisation and reward scaling.

`ppo_update` is the reference and takes any torch optimiser. The learner runs it with
`FlatAdam` (imitation.flat_adam), whose step and gradient clip equal torch.optim.Adam's and
`clip_grad_norm_`'s but act on one flat buffer, a few kernels per step instead of a few per
parameter tensor. tests/algorithms/test_ppo_learner.py checks the learner's updates against
`ppo_update` with torch.optim.Adam. The update is not compiled: torch.compile's first call
costs more than a run shorter than about a million steps saves (bench/ppo_step.py).

Observations may be images or Dicts holding them (`--pixels`: the env's rendered frames,
`imitation.envs.pixels`; `frame_stack` k: the last k frames of each image leaf). The policy then
encodes each image leaf with a CNN (`imitation.policies`), which the update must train: the
rollout keeps the observations themselves, image leaves as uint8 (a float32 copy would be four
times the size), and each minibatch is encoded afresh with gradients. A flat policy's features
are fixed functions of the observation, computed once at collection and reused. An image
policy's observation statistics (with `normalize_observations`) are folded in once per rollout,
after its update, so that the rollout's π_k and the update's π_θ read frames through the same
statistics and the first ratio r_t(θ) is exactly 1.

The rewards optimised are the environment's, or a learned reward's (`reward`, any object with
`relabel(rollout)`, such as `imitation.rewards.RewardNet`); an outer loop that learns a reward
(guided cost learning) calls `collect_rollout` and `update` itself.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable
from contextlib import closing
from dataclasses import dataclass
from typing import Any, Protocol

import gymnasium as gym
import numpy as np
import torch
from torch.distributions import Distribution, kl_divergence

from imitation.algorithms.advantages import compute_gae
from imitation.algorithms.ppo_config import PPOConfig
from imitation.checkpoints import CheckpointData, CheckpointReader, CheckpointWriter, TrainingClock
from imitation.envs.pixels import PIXELS_KEY
from imitation.envs.rollout import Rollout
from imitation.envs.vector import finished_episode_returns, make_observed_env, make_vector_env
from imitation.errors import ImitationError
from imitation.flat_adam import FlatAdam, clip_grad_norm
from imitation.policies import ActorCritic, RunningMeanStd, batch_of_one, make_policy, tensor_tree
from imitation.rewards import flat_batch, tree_index
from imitation.tensors import TensorTree, resolve_device

# ------------------------------------------------------------------------------------------------
# The formulas, as pure functions (tested against values worked by hand).


def clipped_surrogate(ratio: torch.Tensor, advantages: torch.Tensor, clip_range: float) -> torch.Tensor:
    """min(r Â, clip(r, 1-ε, 1+ε) Â) per sample (to be maximised)."""
    return torch.min(ratio * advantages, torch.clamp(ratio, 1.0 - clip_range, 1.0 + clip_range) * advantages)


def policy_kl(old: Distribution, new: Distribution) -> torch.Tensor:
    """D_KL(π_k(·|s) || π_θ(·|s)) per state, old first as in the notes; summed over a Gaussian's action dims."""
    kl = kl_divergence(old, new)
    return kl.reshape(len(kl), -1).sum(-1)


def kl_penalty_objective(
    ratio: torch.Tensor, advantages: torch.Tensor, old: Distribution, new: Distribution, beta: float
) -> torch.Tensor:
    """r Â - β D_KL(π_k || π_θ) per sample (to be maximised)."""
    return ratio * advantages - beta * policy_kl(old, new)


def update_kl_penalty(beta: float, kl: float, target: float) -> float:
    """β ← 2β if D̄_KL ≥ 1.5 δ; β ← β/2 if D̄_KL ≤ δ/1.5; unchanged otherwise."""
    if kl >= 1.5 * target:
        return beta * 2.0
    if kl <= target / 1.5:
        return beta / 2.0
    return beta


# ------------------------------------------------------------------------------------------------
# Reward scaling, and what the environments return


class RewardScaler:
    """Divides rewards by the running std of the discounted return (CleanRL's NormalizeReward):
    keeps the critic's targets at a sane scale whatever the reward's units."""

    def __init__(self, n_envs: int, gamma: float) -> None:
        self.gamma = gamma
        self.returns = np.zeros(n_envs)
        self.stats = RunningMeanStd(())

    def __call__(self, rewards: np.ndarray, dones: np.ndarray) -> np.ndarray:
        self.returns = self.returns * self.gamma + rewards
        self.stats.update(torch.as_tensor(self.returns))
        self.returns[dones] = 0.0
        return np.clip(rewards / np.sqrt(self.stats.var.item() + 1e-8), -10.0, 10.0)


def observation_leaves(name: str, observations: Any) -> dict[str, np.ndarray]:
    """A batch of observations (an array, or a dict of them) as `check_finite_step`'s named arrays."""
    if isinstance(observations, dict):
        return {f"{name}_{key}": np.asarray(value) for key, value in observations.items()}
    return {name: np.asarray(observations)}


def check_finite_step(env_id: str, step: int, copies: np.ndarray | None = None, **values: np.ndarray) -> None:
    """NaN or ±inf from the environment stops training where it enters, naming the env step,
    instead of poisoning the normaliser and surfacing later as a NaN loss. `step` counts the
    vector env's steps before this one (env copy i's step is step + i + 1); row j of each array
    belongs to env copy `copies[j]` (default: j)."""
    for what, array in values.items():
        if array.dtype.kind == "f" and not np.isfinite(array).all():
            row = int(np.argmin(np.isfinite(array).reshape(len(array), -1).all(axis=1)))
            copy = int(copies[row]) if copies is not None else row
            raise ImitationError(
                f"{env_id}: the environment returned a non-finite {what.replace('_', ' ')} at env step {step + copy + 1} "
                f"(env copy {copy}); PPO needs finite observations and rewards"
            )


@dataclass
class UpdateBatch:
    """A rollout flattened for the update: the policy's inputs (`batch_features`), π_k's actions
    and log π_k(a|s), Â and R = Â + V, the critic's V at collection, and π_k's parameters (and σ)
    to rebuild π_k(·|s)."""

    inputs: TensorTree
    actions: torch.Tensor
    log_probs: torch.Tensor
    advantages: torch.Tensor
    returns: torch.Tensor
    values: torch.Tensor
    parameters: torch.Tensor
    old_log_std: torch.Tensor | None


@dataclass
class UpdateStatistics:
    """Means over the update's minibatches (entropy: over the rollout after the update)."""

    policy_loss: float
    value_loss: float
    approx_kl: float
    clip_fraction: float
    entropy: float
    stopped_early: bool


def batch_features(policy: ActorCritic, inputs: TensorTree, index: torch.Tensor | None = None) -> torch.Tensor:
    """The features π_θ and V_θ read, of the update's inputs (at `index`). A flat policy's inputs
    are its features, fixed at collection; an image policy's are its observations, encoded here
    with gradients, so that its CNN learns."""
    if policy.layout is None:
        assert isinstance(inputs, torch.Tensor)
        return inputs if index is None else inputs[index]
    return policy.encode(inputs if index is None else tree_index(inputs, index))


def over_batch(
    policy: ActorCritic, batch: UpdateBatch, size: int, measure: Callable[[torch.Tensor, torch.Tensor], torch.Tensor]
) -> torch.Tensor:
    """`measure(features, index)` of the whole batch without gradients: an image policy's `size`
    samples at a time (its activations for a whole rollout can take gigabytes), a flat policy's
    (features already computed) in one pass."""
    rows = len(batch.log_probs)
    size = size if policy.layout is not None else rows
    with torch.no_grad():
        parts = []
        for start in range(0, rows, size):
            index = torch.arange(start, min(start + size, rows), device=batch.log_probs.device)
            parts.append(measure(batch_features(policy, batch.inputs, index), index))
        return torch.cat(parts)


def ppo_update(
    policy: ActorCritic,
    optimizer: torch.optim.Optimizer | FlatAdam,
    batch: UpdateBatch,
    config: PPOConfig,
    beta: float,
    *,
    update: int = 1,
    n_updates: int = 1,
) -> UpdateStatistics:
    """n_epochs passes over the rollout in shuffled minibatches, each a gradient step on

        -L(θ) + c_v · ½ (V_θ(s) - R)² - c_H · H[π_θ(·|s)]

    with L = L^CLIP or L^KL (β fixed during the update), Â normalised per minibatch, the value
    loss optionally clipped, max(½(V_θ - R)², ½(V_k + clip(V_θ - V_k, ±ε) - R)²), and the global
    gradient norm clipped. With `target_kl`, the epochs stop once the last minibatch's KL
    estimate, mean((r - 1) - log r), passes 1.5 · target_kl. `update` of `n_updates` names the
    update in the error a diverging loss raises."""
    size = len(batch.log_probs)
    # Statistics stay tensors until the update ends: one device sync instead of one per batch.
    statistics: list[torch.Tensor] = []
    stopped_early = False
    for epoch in range(config.n_epochs):
        order = torch.randperm(size, device=batch.log_probs.device)
        for start in range(0, size, config.batch_size):
            index = order[start : start + config.batch_size]
            features = batch_features(policy, batch.inputs, index)
            distribution = policy.distribution(features)
            log_ratio = policy.log_prob(distribution, batch.actions[index]) - batch.log_probs[index]
            ratio = log_ratio.exp()
            advantages = batch.advantages[index]
            if config.normalize_advantages and len(index) > 1:
                advantages = (advantages - advantages.mean()) / (advantages.std() + 1e-8)

            if config.objective == "clip":
                policy_loss = -clipped_surrogate(ratio, advantages, config.clip_range).mean()
            else:
                old = policy.distribution_from(batch.parameters[index], batch.old_log_std)
                policy_loss = -kl_penalty_objective(ratio, advantages, old, distribution, beta).mean()

            new_values, old_values, returns = policy.value(features), batch.values[index], batch.returns[index]
            if config.clip_value_loss:
                clipped_values = old_values + torch.clamp(new_values - old_values, -config.clip_range, config.clip_range)
                value_loss = 0.5 * torch.max((new_values - returns) ** 2, (clipped_values - returns) ** 2).mean()
            else:
                value_loss = 0.5 * ((new_values - returns) ** 2).mean()
            loss = policy_loss + config.value_coef * value_loss
            if config.entropy_coef:
                loss = loss - config.entropy_coef * policy.entropy(distribution).mean()
            if not torch.isfinite(loss):
                raise ImitationError(
                    f"PPO update {update}/{n_updates}, epoch {epoch + 1}: the loss is {loss.item()} "
                    "(diverged; try a lower learning rate, or normalised observations/rewards)"
                )

            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            clip_grad_norm(optimizer, config.max_grad_norm)
            optimizer.step()

            with torch.no_grad():
                approx_kl = ((ratio - 1.0) - log_ratio).mean()
                clip_fraction = ((ratio - 1.0).abs() > config.clip_range).float().mean()
                statistics.append(torch.stack([policy_loss.detach(), value_loss.detach(), approx_kl, clip_fraction]))
        if config.target_kl is not None and statistics[-1][2].item() > 1.5 * config.target_kl:
            stopped_early = True
            break
    policy_loss_mean, value_loss_mean, kl_mean, clip_fraction_mean = torch.stack(statistics).mean(0).tolist()
    entropy = over_batch(policy, batch, config.batch_size, lambda f, _: policy.entropy(policy.distribution(f))).mean().item()
    return UpdateStatistics(policy_loss_mean, value_loss_mean, kl_mean, clip_fraction_mean, entropy, stopped_early)


class RolloutReward(Protocol):
    """A learned reward PPO optimises in place of the environment's: r(s_t, a_t, s_{t+1}) for
    every step of a rollout, shape (T, n_envs)."""

    def relabel(self, rollout: Rollout) -> torch.Tensor: ...


class RemoteRollouts(Protocol):
    """Rollouts collected elsewhere (Ray actors: `imitation.algorithms.ray_rollouts`) into the
    learner's rollout buffers (`rollout_storage`, `buffers`), and the envs' last observations into
    its `observations`."""

    def collect(self, learner: PPO) -> None: ...

    def close(self) -> None: ...


@dataclass
class _Buffers:
    """What a rollout leaves for its update besides the `Rollout` itself: a flat policy's
    features (None for an image policy, which re-encodes the rollout's observations), V(s_t), V of
    truncated episodes' true final states, π_k's distribution parameters, and the rewards after
    scaling. Allocated once and refilled in place."""

    features: torch.Tensor | None
    values: torch.Tensor
    truncated_values: torch.Tensor
    parameters: torch.Tensor
    rewards: torch.Tensor


def observation_storage(space: gym.Space, shape: tuple[int, ...], device: torch.device) -> TensorTree:
    """Zeroed storage for `shape` observations of `space` (a dict of it for a Dict space):
    uint8 leaves, frames above all, stay uint8; Discrete ones are int64, the others float32."""
    if isinstance(space, gym.spaces.Dict):
        return {key: observation_storage(sub, shape, device) for key, sub in space.spaces.items()}
    assert space.shape is not None  # None only for non-array spaces (Graph, Text)
    if isinstance(space, gym.spaces.Discrete):
        dtype = torch.int64
    else:
        dtype = torch.uint8 if space.dtype == np.uint8 else torch.float32
    return torch.zeros((*shape, *space.shape), dtype=dtype, device=device)


def store_observations(storage: TensorTree, index: Any, observations: Any) -> None:
    """storage[index] = observations (a tensor, or a dict of them), leaf by leaf, in the storage's dtype."""
    if isinstance(storage, dict):
        for key, leaf in storage.items():
            store_observations(leaf, index, observations[key])
    else:
        storage[index] = observations.to(storage.dtype)


def stack_observations(observations: list[Any]) -> Any:
    """Single observations (arrays, or dicts of them) as one batch."""
    if isinstance(observations[0], dict):
        return {key: np.stack([observation[key] for observation in observations]) for key in observations[0]}
    return np.stack(observations)


class PPO:
    """The learner's state (π_θ and V_θ, Adam, the normalisers, β, counters, recent returns)
    and its step: one rollout with π_k, then one update. The environments are part of it but
    not of its checkpoint: a resumed run starts new episodes."""

    name = "PPO"
    unit = "update"

    def __init__(
        self, config: PPOConfig, *, reward: RolloutReward | None = None, remote: RemoteRollouts | None = None
    ) -> None:
        config.validate()
        # One thread by default: with two, these small MLPs spend their time synchronising
        # (bench/RESULTS.md, "Why the presets are what they are").
        torch.set_num_threads(config.threads)
        torch.manual_seed(config.seed)
        np.random.seed(config.seed)
        self.config = config
        self.reward = reward
        self.device = device = resolve_device(config.device)
        pixels = config.recipe
        self.remote = remote
        # With remote rollouts the environments live with the workers; one copy here gives the spaces.
        self.envs: gym.vector.VectorEnv | None = None
        if remote is None:
            self.envs = make_vector_env(
                config.env_id, config.n_envs, asynchronous=config.async_envs, pixels=pixels, frame_stack=config.frame_stack
            )
            self.observation_space, self.action_space = self.envs.single_observation_space, self.envs.single_action_space
        else:
            with closing(make_observed_env(config.env_id, pixels, config.frame_stack)) as env:
                self.observation_space, self.action_space = env.observation_space, env.action_space
        self.policy = make_policy(
            self.observation_space,
            self.action_space,
            hidden_sizes=list(config.hidden_sizes),
            activation=config.activation,
            shared_trunk=config.shared_trunk,
            normalize_observations=config.normalize_observations,
            log_std_init=config.log_std_init,
            # A pixel policy reads its frames alone: the state rendered beside them is not its to see.
            observation_keys=config.observation_keys or ([PIXELS_KEY] if pixels is not None else None),
            frame_stack=config.frame_stack,
            cnn=config.cnn,
            pixels=config.pixels,
        ).to(device)
        self.optimizer = FlatAdam(self.policy.parameters(), lr=config.learning_rate, eps=1e-5)
        self.reward_scaler = RewardScaler(config.n_envs, config.gamma) if config.normalize_rewards else None
        self.rollout_size = config.n_steps * config.n_envs
        self.total = -(-config.total_steps // self.rollout_size)  # updates: at least total_steps
        self.updates = 0
        # The first reset folds the first frames into an image policy's statistics at a run's
        # start; a run resumed after an update has them already (and so has a Ray worker's copy
        # of such a run, which counts no updates of its own).
        self.folds_first_frames = True
        self.global_step = 0
        self.beta = config.kl_beta_init
        self.recent_returns: deque[float] = deque(maxlen=20)
        self.recent_optimised_returns: deque[float] = deque(maxlen=20)
        self._optimised_return_accumulator = np.zeros(config.n_envs)
        # Where the time goes (seconds, cumulative): stepping envs, the rollout's forward passes, updates.
        self.timers = {"env": 0.0, "inference": 0.0, "update": 0.0}
        self.clock = TrainingClock()
        self.observations: Any = None  # the envs' current batch: reset at the first rollout, by the update it starts
        self.rollout_storage, self.buffers = self._allocate()

    def _allocate(self) -> tuple[Rollout, _Buffers]:
        shape, device = (self.config.n_steps, self.config.n_envs), self.device
        observation_space, action_shape = self.observation_space, self.action_space.shape
        assert action_shape is not None  # None only for non-array spaces (Graph, Text)
        features = None
        if self.policy.layout is None:
            sample = tensor_tree(batch_of_one(observation_space.sample()), device)
            features = torch.zeros((*shape, self.policy.encode(sample).shape[-1]), device=device)
        # Built from a dict: Rollout's observations are trees here (a tensor, or a dict of them).
        fields: dict[str, Any] = dict(
            observations=observation_storage(observation_space, shape, device),
            actions=torch.zeros((*shape, *action_shape), device=device),
            env_actions=torch.zeros((*shape, *action_shape), device=device),
            next_observations=observation_storage(observation_space, shape, device),
            log_probs=torch.zeros(shape, device=device),
            env_rewards=torch.zeros(shape, device=device),
            terminated=torch.zeros(shape, dtype=torch.bool, device=device),
            truncated=torch.zeros(shape, dtype=torch.bool, device=device),
        )
        buffers = _Buffers(
            features=features,
            values=torch.zeros(shape, device=device),
            truncated_values=torch.zeros(shape, device=device),
            parameters=torch.zeros((*shape, self.policy.action_head.out_features), device=device),
            rewards=torch.zeros(shape, device=device),
        )
        return Rollout(**fields), buffers

    @property
    def completed(self) -> int:
        return self.updates

    @property
    def done(self) -> bool:
        return self.updates >= self.total

    def position(self) -> str:
        return f"update {self.updates}/{self.total}, at step {self.global_step} of {self.total * self.rollout_size}"

    def progress(self, row: dict[str, float]) -> dict[str, str]:
        return {"ret": f"{row['return']:.1f}", "sps": f"{row['steps_per_second']:.0f}"}

    def step(self) -> dict[str, float]:
        """One rollout with π_k, then one update on the env's reward or the learned one."""
        rollout = self.collect_rollout()
        return self.update(rollout, self.reward.relabel(rollout) if self.reward is not None else rollout.env_rewards)

    def collect_rollout(self) -> Rollout:
        """n_steps steps of every env with π_k, sampling a_t ~ π_k(·|s_t) and keeping log π_k(a_t|s_t),
        V(s_t) and π_k's parameters for the update. The returned tensors are refilled by the next
        rollout: copy what must outlive it."""
        if self.remote is not None:
            self.clock.start()
            self.remote.collect(self)
            self.global_step += self.rollout_size
            return self.rollout_storage
        config, policy, device, timers = self.config, self.policy, self.device, self.timers
        rollout, buffers = self.rollout_storage, self.buffers
        assert self.envs is not None  # local rollouts step the learner's own envs
        if self.observations is None:
            self.observations, _ = self.envs.reset(seed=config.seed + self.updates * config.n_envs)
            check_finite_step(config.env_id, -1, **observation_leaves("observation", self.observations))
            if policy.layout is not None and self.folds_first_frames:
                # An image policy's statistics start from the first frames (then grow once per rollout).
                policy.update_normalizer(tensor_tree(self.observations, device))
        self.clock.start()  # wall-clock time from here on, reward learning between updates included
        for t in range(config.n_steps):
            tick = time.perf_counter()
            observation = tensor_tree(self.observations, device)
            store_observations(rollout.observations, t, observation)
            if policy.layout is None:
                policy.update_normalizer(observation)
            with torch.no_grad():
                features = policy.encode(observation)
                if buffers.features is not None:
                    buffers.features[t] = features
                # The parameters are kept so the KL objective can compare π_θ with π_k exactly.
                action, rollout.log_probs[t], buffers.parameters[t] = policy.sample(features)
                buffers.values[t] = policy.value(features)
            rollout.actions[t] = action.reshape(rollout.actions[t].shape)
            env_action = policy.to_env_action(action)
            rollout.env_actions[t] = torch.as_tensor(env_action, device=device).reshape(rollout.env_actions[t].shape)
            tock = time.perf_counter()
            timers["inference"] += tock - tick
            self.observations, reward, terminated, truncated, info = self.envs.step(env_action)
            tick = time.perf_counter()
            timers["env"] += tick - tock
            env_step = self.global_step + t * config.n_envs
            check_finite_step(
                config.env_id, env_step, **observation_leaves("observation", self.observations), reward=np.asarray(reward)
            )
            self.recent_returns.extend(finished_episode_returns(info))
            rollout.env_rewards[t] = torch.as_tensor(reward, dtype=torch.float32, device=device)
            rollout.terminated[t] = torch.as_tensor(terminated, device=device)
            rollout.truncated[t] = torch.as_tensor(truncated, device=device)
            store_observations(rollout.next_observations, t, tensor_tree(self.observations, device))
            ended = np.flatnonzero(terminated | truncated)
            if ended.size:
                # The episode's true final state (the env has already reset to a new one).
                final = stack_observations([info["final_obs"][i] for i in ended])
                check_finite_step(config.env_id, env_step, ended, **observation_leaves("final_observation", final))
                rows = torch.as_tensor(ended, device=device)
                store_observations(rollout.next_observations, (t, rows), tensor_tree(final, device))
            if truncated.any():
                # Bootstrap truncated episodes from their true final state, not the reset state.
                with torch.no_grad():
                    next_observation = tree_index(rollout.next_observations, t)
                    buffers.truncated_values[t] = policy.value(policy.encode(next_observation))
            timers["inference"] += time.perf_counter() - tick
        self.global_step += self.rollout_size
        return rollout

    def update(self, rollout: Rollout, rewards: torch.Tensor) -> dict[str, float]:
        """One update on the rollout just collected, optimising `rewards` (T, n_envs): GAE, then
        `ppo_update`'s epochs, then β's adaptation; the row of metrics to log."""
        config, policy, buffers = self.config, self.policy, self.buffers
        started = time.perf_counter()
        if config.anneal_lr:
            self.optimizer.param_groups[0]["lr"] = (1.0 - self.updates / self.total) * config.learning_rate
        self._store_rewards(rewards, rollout)
        with torch.no_grad():
            last_values = policy.value(policy.encode(tensor_tree(self.observations, self.device)))
        terminated, truncated = rollout.terminated, rollout.truncated
        next_values = torch.where(truncated, buffers.truncated_values, torch.cat([buffers.values[1:], last_values[None]]))
        advantages, returns = compute_gae(
            buffers.rewards,
            buffers.values,
            next_values,
            terminated,
            truncated,
            gamma=config.gamma,
            gae_lambda=config.gae_lambda,
        )
        size = self.rollout_size
        batch = UpdateBatch(
            inputs=flat_batch(rollout.observations, 2) if buffers.features is None else buffers.features.reshape(size, -1),
            actions=rollout.actions.reshape(size, *rollout.actions.shape[2:]),
            log_probs=rollout.log_probs.reshape(-1),
            advantages=advantages.reshape(-1),
            returns=returns.reshape(-1),
            values=buffers.values.reshape(-1),
            parameters=buffers.parameters.reshape(size, -1),
            old_log_std=policy.log_std.detach().clone() if policy.is_continuous else None,
        )
        measured = ppo_update(policy, self.optimizer, batch, config, self.beta, update=self.updates + 1, n_updates=self.total)
        mean_kl = measured.approx_kl
        if config.objective == "kl":

            def kl(features: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
                old = policy.distribution_from(batch.parameters[index], batch.old_log_std)
                return policy_kl(old, policy.distribution(features))

            mean_kl = over_batch(policy, batch, config.batch_size, kl).mean().item()
            self.beta = update_kl_penalty(self.beta, mean_kl, config.kl_target)
        if policy.layout is not None:
            policy.update_normalizer(batch.inputs)  # after the update: see the module docstring
        self.updates += 1
        self.timers["update"] += time.perf_counter() - started
        return self._row(measured, mean_kl, batch)

    def _row(self, measured: UpdateStatistics, mean_kl: float, batch: UpdateBatch) -> dict[str, float]:
        """The update's row of metrics: returns (the env's and the one optimised), losses, KL, speed."""
        explained_variance = 1.0 - float(torch.var(batch.returns - batch.values) / (torch.var(batch.returns) + 1e-8))
        return {
            "step": float(self.global_step),
            "return": float(np.mean(self.recent_returns)) if self.recent_returns else float("nan"),
            "optimised_return": float(np.mean(self.recent_optimised_returns))
            if self.recent_optimised_returns
            else float("nan"),
            "policy_loss": measured.policy_loss,
            "value_loss": measured.value_loss,
            "entropy": measured.entropy,
            "kl": mean_kl,
            "kl_beta": self.beta if self.config.objective == "kl" else float("nan"),
            "clip_fraction": measured.clip_fraction,
            "explained_variance": explained_variance,
            "learning_rate": self.optimizer.param_groups[0]["lr"],
            "early_stop": float(measured.stopped_early),
            "steps_per_second": self.global_step / self.clock.seconds,
            "seconds_env": self.timers["env"],
            "seconds_inference": self.timers["inference"],
            "seconds_update": self.timers["update"],
        }

    def _store_rewards(self, rewards: torch.Tensor, rollout: Rollout) -> None:
        """The rewards optimised, scaled by the running return std when configured, into the
        update's buffer; their undiscounted episode returns into `recent_optimised_returns`."""
        optimised = rewards.detach().to(device=self.device, dtype=torch.float32).reshape(self.buffers.rewards.shape)
        self._check_learned_reward(optimised)
        dones = (rollout.terminated | rollout.truncated).cpu().numpy()
        for t, step_rewards in enumerate(optimised.cpu().numpy()):
            self._optimised_return_accumulator += step_rewards
            for i in np.flatnonzero(dones[t]):
                self.recent_optimised_returns.append(float(self._optimised_return_accumulator[i]))
                self._optimised_return_accumulator[i] = 0.0
            scaled = self.reward_scaler(step_rewards, dones[t]) if self.reward_scaler is not None else step_rewards
            self.buffers.rewards[t] = torch.as_tensor(scaled, device=self.device)

    def _check_learned_reward(self, rewards: torch.Tensor) -> None:
        """A learned reward gone NaN or infinite stops training naming the env step it entered at."""
        finite = torch.isfinite(rewards)
        if bool(finite.all()):
            return
        t, copy = (int(i) for i in torch.nonzero(~finite)[0])
        step = self.global_step - self.rollout_size + t * self.config.n_envs + copy + 1
        raise ImitationError(
            f"{self.config.env_id}: the learned reward is not finite at env step {step} (env copy {copy}), "
            f"in PPO update {self.updates + 1}/{self.total}"
        )

    def close(self) -> None:
        if self.envs is not None:
            self.envs.close()
        if self.remote is not None:
            self.remote.close()

    def state_dict(self) -> CheckpointData:
        """Everything to continue after this update: networks, Adam, the normalisers, β, the
        counters, the recent returns and the random generators (live tensors: the loop copies them)."""
        checkpoint = CheckpointWriter(
            update=self.updates,
            global_step=self.global_step,
            beta=self.beta,
            policy=self.policy.config.to_json(),
            recent_returns=list(self.recent_returns),
            recent_optimised_returns=list(self.recent_optimised_returns),
            timers=self.timers,
        )
        checkpoint.module("policy", self.policy.state_dict())
        checkpoint.optimizer(self.optimizer)
        checkpoint.rng()
        checkpoint.clock(self.clock)
        if self.reward_scaler is not None:
            checkpoint.module("reward_scaler", self.reward_scaler.stats.state_dict())
        return checkpoint.data()

    def load_state_dict(self, checkpoint: CheckpointData) -> None:
        with CheckpointReader(checkpoint, "PPO") as saved:
            self.policy.load_state_dict(saved.module("policy"))
            saved.optimizer(self.optimizer)
            if self.reward_scaler is not None:
                self.reward_scaler.stats.load_state_dict(saved.module("reward_scaler"))
            saved.rng()
            self.recent_returns.extend(saved.state["recent_returns"])
            self.recent_optimised_returns.extend(saved.state["recent_optimised_returns"])
            self.timers.update(saved.state["timers"])
            self.global_step, self.beta = int(saved.state["global_step"]), float(saved.state["beta"])
            saved.clock(self.clock)
            self.updates = saved.counter("update", "next update", 0, self.total)
            self.folds_first_frames = self.updates == 0
