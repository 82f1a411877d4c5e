"""Proximal policy optimisation (theory notes §3–4), readable top to bottom like CleanRL's ppo.py.

Each update collects n_steps × n_envs transitions with the current policy π_k, then takes
n_epochs passes of minibatch gradient steps on one of the notes' two objectives:

- clipped surrogate:  L^CLIP(θ) = E[ min( r_t(θ) Â_t, clip(r_t(θ), 1-ε, 1+ε) Â_t ) ],
  r_t(θ) = π_θ(a_t|s_t) / π_k(a_t|s_t)
- adaptive KL penalty: L^KL(θ) = E[ r_t(θ) Â_t ] - β · E_s[ D_KL(π_k(·|s) || π_θ(·|s)) ],
  after each update β ← 2β if D̄_KL ≥ 1.5 δ, β ← β/2 if D̄_KL ≤ δ/1.5 (target δ)

with advantages from truncated GAE(γ, λ):

    δ_t = r_t + γ (1 - term_t) V(s_{t+1}) - V(s_t)
    Â_t = δ_t + γ λ (1 - done_t) Â_{t+1}

where done_t = term_t or trunc_t. On truncation (time limit) s_{t+1} is the true final state of
the episode and V(s_{t+1}) is bootstrapped; on termination it is not. The critic regresses on
R_t = Â_t + V(s_t). The loss minimised is -L + c_v · (V - R)² / 2 - c_H · H[π].

The implementation details (CleanRL's "37 details") each appear as a visible line: vectorised
envs, orthogonal init (in imitation.policies), Adam eps 1e-5, learning-rate annealing,
minibatch advantage normalisation, optional value clipping, entropy bonus, global gradient
clipping, optional KL early stop, running observation normalisation and reward scaling.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass, field, fields
from typing import Any, Callable

import gymnasium as gym
import numpy as np
import torch
from torch.distributions import Distribution, kl_divergence
from tqdm import tqdm

from imitation.checkpoints import (
    CheckpointData,
    Checkpointable,
    Checkpointing,
    StopAtBoundary,
    TrainingInterrupted,
    checked_counter,
    floats,
    optimizer_checkpoint,
    prefixed,
    restore_optimizer,
    restore_rng,
    rng_checkpoint,
    snapshot,
    unprefixed,
)
from imitation.data.loader import resolve_device
from imitation.envs.make import make_env
from imitation.errors import ImitationError
from imitation.policies import ActorCritic, RunningMeanStd, make_policy

OBJECTIVES = ("clip", "kl")


@dataclass(kw_only=True)
class PPOConfig:
    """Hyperparameters; `ppo_defaults(env_id)` gives tuned values for known environments."""

    env_id: str
    total_steps: int = 100_000
    objective: str = "clip"
    n_envs: int = 4
    n_steps: int = 128
    batch_size: int = 128
    n_epochs: int = 4
    gamma: float = 0.99
    gae_lambda: float = 0.95
    learning_rate: float = 2.5e-4
    anneal_lr: bool = True
    clip_range: float = 0.2
    clip_value_loss: bool = False
    value_coef: float = 0.5
    entropy_coef: float = 0.0
    max_grad_norm: float = 0.5
    target_kl: float | None = None
    kl_target: float = 0.01
    kl_beta_init: float = 1.0
    normalize_advantages: bool = True
    normalize_observations: bool = False
    normalize_rewards: bool = False
    hidden_sizes: list[int] = field(default_factory=lambda: [64, 64])
    activation: str = "tanh"
    shared_trunk: bool = False
    log_std_init: float = 0.0
    async_envs: bool = False
    seed: int = 0
    device: str = "auto"
    threads: int = 1
    reward_run: str | None = None

    def validate(self) -> None:
        if self.objective not in OBJECTIVES:
            raise ImitationError(f"--objective must be one of {', '.join(OBJECTIVES)}, got {self.objective!r}")
        for name in ("total_steps", "n_envs", "n_steps", "batch_size", "n_epochs"):
            if getattr(self, name) < 1:
                raise ImitationError(f"{name} must be at least 1, got {getattr(self, name)}")
        if self.total_steps < self.n_envs * self.n_steps:
            raise ImitationError(f"--steps {self.total_steps} is less than one rollout ({self.n_envs} envs × {self.n_steps} steps)")
        if not 0 < self.learning_rate < 1e30:  # NaN fails too; from ~1e37 Adam's step overflows float32
            raise ImitationError(f"learning_rate must be a positive number below 1e30, got {self.learning_rate}")

    @staticmethod
    def from_json(data: dict[str, Any]) -> PPOConfig:
        known = {f.name for f in fields(PPOConfig)}
        return PPOConfig(**{key: value for key, value in data.items() if key in known})


# rl-baselines3-zoo's tuned settings where we have them (Pendulum departs from them, see there);
# CleanRL's defaults otherwise.
_ENV_DEFAULTS: dict[str, dict[str, Any]] = {
    "CartPole-v1": dict(n_envs=8, n_steps=32, batch_size=256, gamma=0.98, gae_lambda=0.8, n_epochs=20, learning_rate=1e-3),
    # The zoo reaches Pendulum with gSDE; with a state-independent log-std, an entropy bonus keeps
    # σ from collapsing before the swing-up is found (measured: -177, -186, -163 at 200k steps,
    # seeds 0-2; without it about -530).
    "Pendulum-v1": dict(
        n_envs=4, n_steps=1024, batch_size=64, gamma=0.9, gae_lambda=0.95, n_epochs=10, learning_rate=1e-3,
        normalize_observations=True, log_std_init=-0.5, entropy_coef=0.01,
    ),
    "MountainCarContinuous-v0": dict(n_envs=1, n_steps=2048, batch_size=64, n_epochs=10, learning_rate=3e-4, normalize_observations=True),
}
# Without termination, most early steps are spent after the fall, where nothing can be learnt;
# the policy turned near-deterministic by 13k steps and recovered slowly (100k steps: 52 and
# 188). An entropy bonus keeps it exploring: 500, 500, 475 at 200k steps, seeds 0-2.
_ENV_DEFAULTS["imitation/CartPoleFixedHorizon-v0"] = _ENV_DEFAULTS["CartPole-v1"] | {"entropy_coef": 0.01}
_CONTINUOUS_DEFAULTS = dict(n_envs=1, n_steps=2048, batch_size=64, n_epochs=10, learning_rate=3e-4, normalize_observations=True, normalize_rewards=True)


def ppo_defaults(env_id: str, action_space: gym.Space | None = None) -> dict[str, Any]:
    """Settings that make `train ppo --env ID` work without flags."""
    if env_id in _ENV_DEFAULTS:
        return dict(_ENV_DEFAULTS[env_id])
    if isinstance(action_space, gym.spaces.Box):
        return dict(_CONTINUOUS_DEFAULTS)
    return {}


def learned_reward_ppo_defaults(env_id: str, action_space: gym.Space | None = None) -> dict[str, Any]:
    """`ppo_defaults` for optimising a learned reward: rewards scaled by their running return
    std, since a learned reward's scale is arbitrary (and drifts while it is being learned)."""
    return ppo_defaults(env_id, action_space) | {"normalize_rewards": True}


# ------------------------------------------------------------------------------------------------
# The formulas, as pure functions (tested against values worked by hand).


def compute_gae(
    rewards: torch.Tensor,
    values: torch.Tensor,
    next_values: torch.Tensor,
    terminated: torch.Tensor,
    truncated: torch.Tensor,
    *,
    gamma: float,
    gae_lambda: float,
) -> tuple[torch.Tensor, torch.Tensor]:
    """GAE over a rollout of shape (T, n_envs); returns (advantages, returns = Â + V).

    `next_values[t]` is V(s_{t+1}) of the state that followed step t: the next state in the
    rollout, the true final state when step t was truncated, anything when it terminated."""
    not_terminal = 1.0 - terminated.float()
    continues = 1.0 - (terminated | truncated).float()
    deltas = rewards + gamma * not_terminal * next_values - values
    advantages = torch.zeros_like(rewards)
    running = torch.zeros_like(rewards[0])
    for t in reversed(range(rewards.shape[0])):
        running = deltas[t] + gamma * gae_lambda * continues[t] * running
        advantages[t] = running
    return advantages, advantages + values


def clipped_surrogate(ratio: torch.Tensor, advantages: torch.Tensor, clip_range: float) -> torch.Tensor:
    """min(r Â, clip(r, 1-ε, 1+ε) Â) per sample (to be maximised)."""
    return torch.min(ratio * advantages, torch.clamp(ratio, 1.0 - clip_range, 1.0 + clip_range) * advantages)


def policy_kl(old: Distribution, new: Distribution) -> torch.Tensor:
    """D_KL(π_k(·|s) || π_θ(·|s)) per state, old first as in the notes; summed over a Gaussian's action dims."""
    kl = kl_divergence(old, new)
    return kl.reshape(len(kl), -1).sum(-1)


def kl_penalty_objective(ratio: torch.Tensor, advantages: torch.Tensor, old: Distribution, new: Distribution, beta: float) -> torch.Tensor:
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
# Environments and reward scaling


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


def make_vector_env(
    env_id: str,
    n_envs: int,
    *,
    asynchronous: bool = False,
    wrap: Callable[[gym.Env], gym.Env] | None = None,
) -> gym.vector.VectorEnv:
    """n copies of env_id with same-step autoreset (the final observation comes in
    info["final_obs"], so truncated episodes can be bootstrapped from their true last state).
    Episode statistics are recorded inside `wrap`, so they are of the environment's own reward."""
    make_env(env_id).close()  # fail here, with one line, on an unknown id

    def factory() -> gym.Env:
        env = gym.wrappers.RecordEpisodeStatistics(make_env(env_id))
        return wrap(env) if wrap is not None else env

    if asynchronous:
        # spawn, not fork: forking a process that already runs torch threads can deadlock.
        return gym.vector.AsyncVectorEnv([factory] * n_envs, autoreset_mode=gym.vector.AutoresetMode.SAME_STEP, context="spawn")
    return gym.vector.SyncVectorEnv([factory] * n_envs, autoreset_mode=gym.vector.AutoresetMode.SAME_STEP)


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


def finished_episode_returns(info: dict[str, Any]) -> list[float]:
    """True returns of the episodes that ended at this vector step."""
    final = info.get("final_info", {})
    if "episode" not in final:
        return []
    episode = final["episode"]
    return [float(r) for r in episode["r"][episode["_r"]]]


# ------------------------------------------------------------------------------------------------
# Training


@dataclass
class Rollout:
    """One rollout as the environment saw it, (T, n_envs) leading dims: what a learned reward
    needs to relabel it (`next_observations` holds the true final state where an episode ended)
    and what importance weights need (`log_probs`, log π_k(a_t|s_t) of the sampled actions)."""

    observations: torch.Tensor
    actions: torch.Tensor
    env_actions: torch.Tensor
    next_observations: torch.Tensor
    log_probs: torch.Tensor
    env_rewards: torch.Tensor
    terminated: torch.Tensor
    truncated: torch.Tensor


# Given each rollout and the current policy, returns the (T, n_envs) rewards PPO optimises in
# place of the env's: a learned reward relabelling the rollout (and, for IRL, learning from it).
# A hook that learns (GCL) is also `Checkpointable`, so that its state is in PPO's checkpoints.
RolloutRewards = Callable[[Rollout, ActorCritic], torch.Tensor]


@dataclass
class PPOResult:
    policy: ActorCritic
    history: list[dict[str, float]]
    reward_scaler: RewardScaler | None
    steps: int
    seconds: float


@dataclass
class UpdateBatch:
    """A rollout flattened for the update: the encoded states, π_k's actions and log π_k(a|s),
    Â and R = Â + V, the critic's V at collection, and π_k's parameters (and σ) to rebuild π_k(·|s)."""

    features: torch.Tensor
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


def ppo_update(
    policy: ActorCritic, optimizer: torch.optim.Optimizer, batch: UpdateBatch, config: PPOConfig, beta: float, *, update: int = 1, n_updates: int = 1
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
            distribution = policy.distribution(batch.features[index])
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

            new_values, old_values, returns = policy.value(batch.features[index]), batch.values[index], batch.returns[index]
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
            torch.nn.utils.clip_grad_norm_(policy.parameters(), config.max_grad_norm, foreach=True)
            optimizer.step()

            with torch.no_grad():
                approx_kl = ((ratio - 1.0) - log_ratio).mean()
                clip_fraction = ((ratio - 1.0).abs() > config.clip_range).float().mean()
                statistics.append(torch.stack([policy_loss.detach(), value_loss.detach(), approx_kl, clip_fraction]))
        if config.target_kl is not None and statistics[-1][2].item() > 1.5 * config.target_kl:
            stopped_early = True
            break
    policy_loss_mean, value_loss_mean, kl_mean, clip_fraction_mean = torch.stack(statistics).mean(0).tolist()
    with torch.no_grad():
        entropy = policy.entropy(policy.distribution(batch.features)).mean().item()
    return UpdateStatistics(policy_loss_mean, value_loss_mean, kl_mean, clip_fraction_mean, entropy, stopped_early)


def train_ppo(
    config: PPOConfig,
    *,
    wrap_env: Callable[[gym.Env], gym.Env] | None = None,
    rollout_rewards: RolloutRewards | None = None,
    log: Callable[[dict[str, float]], None] | None = None,
    progress: bool = True,
    checkpoints: Checkpointing | None = None,
) -> PPOResult:
    """Train an actor-critic on config.env_id; `log` receives one row of metrics per update.
    With `rollout_rewards`, each rollout's rewards are replaced by what it returns before the
    advantages are computed; the logged "return" stays the env's own.

    With `checkpoints`, a checkpoint is saved every tenth of the run (by default), Ctrl-C stops
    after the current update with a checkpoint saved (TrainingInterrupted), and a run given
    `checkpoints.resume` continues from one (see "Checkpoints" at the end of this module); a
    `Checkpointable` `rollout_rewards` is saved and restored with the rest."""
    config.validate()
    # Measured on 2 cores: one thread runs these small MLPs ~10× faster than two, which
    # spend their time synchronising.
    torch.set_num_threads(config.threads)
    torch.manual_seed(config.seed)
    np.random.seed(config.seed)
    device = resolve_device(config.device)
    envs = make_vector_env(config.env_id, config.n_envs, asynchronous=config.async_envs, wrap=wrap_env)
    try:
        with StopAtBoundary(enabled=checkpoints is not None) as stop:
            return _train(config, envs, device, rollout_rewards, log, progress, checkpoints, stop)
    finally:
        envs.close()


def _train(
    config: PPOConfig, envs: gym.vector.VectorEnv, device: torch.device, rollout_rewards: RolloutRewards | None, log: Callable | None, progress: bool,
    checkpoints: Checkpointing | None, stop: StopAtBoundary,
) -> PPOResult:
    policy = make_policy(
        envs.single_observation_space,
        envs.single_action_space,
        hidden_sizes=list(config.hidden_sizes),
        activation=config.activation,
        shared_trunk=config.shared_trunk,
        normalize_observations=config.normalize_observations,
        log_std_init=config.log_std_init,
    ).to(device)
    optimizer = torch.optim.Adam(policy.parameters(), lr=config.learning_rate, eps=1e-5)
    reward_scaler = RewardScaler(config.n_envs, config.gamma) if config.normalize_rewards else None

    n_steps, n_envs = config.n_steps, config.n_envs
    rollout_size = n_steps * n_envs
    n_updates = -(-config.total_steps // rollout_size)  # at least total_steps
    feature_size = policy.encode(torch.as_tensor(envs.single_observation_space.sample()[None], device=device)).shape[-1]
    action_shape = envs.single_action_space.shape
    observation_space = envs.single_observation_space
    observation_dtype = torch.int64 if isinstance(observation_space, gym.spaces.Discrete) else torch.float32
    raw_observations = torch.zeros((n_steps, n_envs, *observation_space.shape), dtype=observation_dtype, device=device)
    next_observations = torch.zeros_like(raw_observations)
    env_actions = torch.zeros((n_steps, n_envs, *action_shape), device=device)
    env_rewards = torch.zeros((n_steps, n_envs), device=device)
    features = torch.zeros((n_steps, n_envs, feature_size), device=device)
    actions = torch.zeros((n_steps, n_envs, *action_shape), device=device)
    log_probs = torch.zeros((n_steps, n_envs), device=device)
    rewards = torch.zeros((n_steps, n_envs), device=device)
    terminated = torch.zeros((n_steps, n_envs), dtype=torch.bool, device=device)
    truncated = torch.zeros((n_steps, n_envs), dtype=torch.bool, device=device)
    values = torch.zeros((n_steps, n_envs), device=device)
    truncated_values = torch.zeros((n_steps, n_envs), device=device)
    distribution_parameters = torch.zeros((n_steps, n_envs, policy.action_head.out_features), device=device)

    recent_returns: deque[float] = deque(maxlen=20)
    recent_optimised_returns: deque[float] = deque(maxlen=20)
    optimised_return_accumulator = np.zeros(n_envs)
    history: list[dict[str, float]] = []
    beta = config.kl_beta_init
    # Where the time goes (seconds, cumulative): stepping envs, the rollout's forward passes, updates.
    timers = {"env": 0.0, "inference": 0.0, "update": 0.0}
    started = time.perf_counter()
    global_step = 0
    first_update = 0
    learner = rollout_rewards if isinstance(rollout_rewards, Checkpointable) else None
    if checkpoints is not None and checkpoints.resume is not None:
        # Continue an interrupted run: networks, optimiser, normalisers, counters and logs as at
        # its checkpoint. The environments' state is not saved: they start new episodes.
        first_update, global_step, beta, elapsed = restore_ppo_checkpoint(
            checkpoints.resume, policy=policy, optimizer=optimizer, reward_scaler=reward_scaler, history=history,
            recent_returns=recent_returns, recent_optimised_returns=recent_optimised_returns, timers=timers, learner=learner,
        )
        first_update = checked_counter(first_update, "next update", 0, n_updates)
        started -= elapsed

    observations, _ = envs.reset(seed=config.seed + first_update * config.n_envs)
    check_finite_step(config.env_id, -1, observation=observations)
    bar = tqdm(total=n_updates * rollout_size, initial=global_step, desc=f"ppo {config.env_id}", unit="step", disable=None if progress else True, dynamic_ncols=True)
    for update in range(first_update, n_updates):
        if config.anneal_lr:
            optimizer.param_groups[0]["lr"] = (1.0 - update / n_updates) * config.learning_rate

        # -- rollout with π_k ---------------------------------------------------------------
        for t in range(n_steps):
            tick = time.perf_counter()
            observation_tensor = torch.as_tensor(observations, device=device)
            raw_observations[t] = observation_tensor
            policy.update_normalizer(observation_tensor)
            with torch.no_grad():
                features[t] = policy.encode(observation_tensor)
                # The parameters are kept so the KL objective can compare π_θ with π_k exactly.
                action, log_probs[t], distribution_parameters[t] = policy.sample(features[t])
                values[t] = policy.value(features[t])
            actions[t] = action.reshape(actions[t].shape)
            env_action = policy.to_env_action(action)
            env_actions[t] = torch.as_tensor(env_action, device=device).reshape(env_actions[t].shape)
            tock = time.perf_counter()
            timers["inference"] += tock - tick
            observations, reward, term, trunc, info = envs.step(env_action)
            tick = time.perf_counter()
            timers["env"] += tick - tock
            check_finite_step(config.env_id, global_step + t * n_envs, observation=observations, reward=np.asarray(reward))
            recent_returns.extend(finished_episode_returns(info))
            env_rewards[t] = torch.as_tensor(reward, dtype=torch.float32, device=device)
            terminated[t] = torch.as_tensor(term, device=device)
            truncated[t] = torch.as_tensor(trunc, device=device)
            next_observations[t] = torch.as_tensor(observations, device=device)
            ended = np.flatnonzero(term | trunc)
            if ended.size:
                # The episode's true final state (the env has already reset to a new one).
                final = np.stack([info["final_obs"][i] for i in ended])
                check_finite_step(config.env_id, global_step + t * n_envs, ended, final_observation=final)
                next_observations[t, torch.as_tensor(ended, device=device)] = torch.as_tensor(final, device=device).to(observation_dtype)
            if trunc.any():
                # Bootstrap truncated episodes from their true final state, not the reset state.
                with torch.no_grad():
                    truncated_values[t] = policy.value(policy.encode(next_observations[t]))
            timers["inference"] += time.perf_counter() - tick
        global_step += rollout_size
        update_started = time.perf_counter()
        if rollout_rewards is not None:
            rollout = Rollout(
                observations=raw_observations, actions=actions, env_actions=env_actions, next_observations=next_observations,
                log_probs=log_probs, env_rewards=env_rewards, terminated=terminated, truncated=truncated,
            )
            optimised = rollout_rewards(rollout, policy).detach().to(device=device, dtype=torch.float32).reshape(n_steps, n_envs)
            if not torch.isfinite(optimised).all():
                raise ImitationError(f"PPO update {update + 1}/{n_updates}: the learned reward is NaN or infinite on this rollout")
        else:
            optimised = env_rewards
        dones = (terminated | truncated).cpu().numpy()
        for t, step_rewards in enumerate(optimised.cpu().numpy()):
            optimised_return_accumulator += step_rewards
            for i in np.flatnonzero(dones[t]):
                recent_optimised_returns.append(float(optimised_return_accumulator[i]))
                optimised_return_accumulator[i] = 0.0
            rewards[t] = torch.as_tensor(reward_scaler(step_rewards, dones[t]) if reward_scaler is not None else step_rewards, device=device)

        with torch.no_grad():
            last_values = policy.value(policy.encode(torch.as_tensor(observations, device=device)))
        following = torch.cat([values[1:], last_values[None]])
        next_values = torch.where(truncated, truncated_values, following)
        advantages, returns = compute_gae(
            rewards, values, next_values, terminated, truncated, gamma=config.gamma, gae_lambda=config.gae_lambda
        )

        # -- n_epochs of minibatch updates ---------------------------------------------------
        batch = UpdateBatch(
            features=features.reshape(rollout_size, -1), actions=actions.reshape(rollout_size, *action_shape), log_probs=log_probs.reshape(-1),
            advantages=advantages.reshape(-1), returns=returns.reshape(-1), values=values.reshape(-1),
            parameters=distribution_parameters.reshape(rollout_size, -1), old_log_std=policy.log_std.detach().clone() if policy.is_continuous else None,
        )
        measured = ppo_update(policy, optimizer, batch, config, beta, update=update + 1, n_updates=n_updates)
        mean_kl = measured.approx_kl
        if config.objective == "kl":
            with torch.no_grad():
                mean_kl = policy_kl(policy.distribution_from(batch.parameters, batch.old_log_std), policy.distribution(batch.features)).mean().item()
            beta = update_kl_penalty(beta, mean_kl, config.kl_target)

        timers["update"] += time.perf_counter() - update_started
        explained_variance = 1.0 - float(torch.var(batch.returns - batch.values) / (torch.var(batch.returns) + 1e-8))
        elapsed = time.perf_counter() - started
        row = {
            "step": float(global_step),
            "return": float(np.mean(recent_returns)) if recent_returns else float("nan"),
            "optimised_return": float(np.mean(recent_optimised_returns)) if recent_optimised_returns else float("nan"),
            "policy_loss": measured.policy_loss,
            "value_loss": measured.value_loss,
            "entropy": measured.entropy,
            "kl": mean_kl,
            "kl_beta": beta if config.objective == "kl" else float("nan"),
            "clip_fraction": measured.clip_fraction,
            "explained_variance": explained_variance,
            "learning_rate": optimizer.param_groups[0]["lr"],
            "early_stop": float(measured.stopped_early),
            "steps_per_second": global_step / elapsed,
            "seconds_env": timers["env"],
            "seconds_inference": timers["inference"],
            "seconds_update": timers["update"],
        }
        history.append(row)
        if log is not None:
            log(row)
        bar.update(rollout_size)
        bar.set_postfix(ret=f"{row['return']:.1f}", sps=f"{row['steps_per_second']:.0f}")

        # -- checkpoint every tenth of the run; stop here if Ctrl-C was pressed (unless done) ----
        interrupted = stop.requested and update + 1 < n_updates
        if checkpoints is not None and (interrupted or ((update + 1) % checkpoints.interval(n_updates) == 0 and update + 1 < n_updates)):
            checkpoints.save(*ppo_checkpoint(
                update + 1, global_step, beta, time.perf_counter() - started, policy=policy, optimizer=optimizer, reward_scaler=reward_scaler,
                history=history, recent_returns=recent_returns, recent_optimised_returns=recent_optimised_returns, timers=timers, learner=learner,
            ))
        if interrupted:
            bar.close()
            raise TrainingInterrupted(f"PPO stopped after update {update + 1}/{n_updates}, at step {global_step} of {n_updates * rollout_size}")
    bar.close()
    return PPOResult(policy=policy, history=history, reward_scaler=reward_scaler, steps=global_step, seconds=time.perf_counter() - started)


# ------------------------------------------------------------------------------------------------
# Checkpoints (imitation.checkpoints): tensors to safetensors, the rest to JSON, nothing pickled.


def ppo_checkpoint(
    next_update: int, global_step: int, beta: float, seconds: float, *, policy: ActorCritic, optimizer: torch.optim.Optimizer,
    reward_scaler: RewardScaler | None, history: list[dict[str, float]], recent_returns: deque[float],
    recent_optimised_returns: deque[float], timers: dict[str, float], learner: Checkpointable | None = None,
) -> CheckpointData:
    """Everything `restore_ppo_checkpoint` needs to continue training after update `next_update`,
    the reward `learner`'s state included."""
    optimizer_tensors, optimizer_state = optimizer_checkpoint(optimizer, "optimizer")
    rng_tensors, rng_state = rng_checkpoint()
    tensors = prefixed("policy", policy.state_dict()) | optimizer_tensors | rng_tensors
    if reward_scaler is not None:
        tensors |= prefixed("reward_scaler", reward_scaler.stats.state_dict())
    state = {
        "update": next_update, "global_step": global_step, "beta": beta, "seconds": seconds, "policy": policy.config.to_json(),
        "optimizer": optimizer_state, "rng": rng_state, "history": history, "recent_returns": list(recent_returns),
        "recent_optimised_returns": list(recent_optimised_returns), "timers": timers,
    }
    if learner is not None:
        learner_tensors, state["learner"] = learner.checkpoint()
        tensors |= prefixed("learner", learner_tensors)
    return snapshot(tensors, state)


def restore_ppo_checkpoint(
    checkpoint: CheckpointData, *, policy: ActorCritic, optimizer: torch.optim.Optimizer, reward_scaler: RewardScaler | None,
    history: list[dict[str, float]], recent_returns: deque[float], recent_optimised_returns: deque[float], timers: dict[str, float],
    learner: Checkpointable | None = None,
) -> tuple[int, int, float, float]:
    """Load a `ppo_checkpoint` into fresh objects (the containers are filled in place); returns
    (next update, global step, β, seconds trained so far)."""
    tensors, state = checkpoint
    try:
        policy.load_state_dict(unprefixed("policy", tensors))
        restore_optimizer(optimizer, tensors, state["optimizer"], "optimizer")
        if reward_scaler is not None:
            reward_scaler.stats.load_state_dict(unprefixed("reward_scaler", tensors))
        restore_rng(tensors, state["rng"])
        history += [floats(row) for row in state["history"]]
        recent_returns.extend(state["recent_returns"])
        recent_optimised_returns.extend(state["recent_optimised_returns"])
        timers.update(state["timers"])
        if learner is not None:
            learner.restore((unprefixed("learner", tensors), state["learner"]))
        return int(state["update"]), int(state["global_step"]), float(state["beta"]), float(state["seconds"])
    except (KeyError, TypeError, ValueError, RuntimeError) as error:
        raise ImitationError(f"the checkpoint does not fit this PPO run ({type(error).__name__}: {str(error).splitlines()[0]})") from None
