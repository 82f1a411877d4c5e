"""Policy gradient from first principles (docs/THEORY.md §2–3): REINFORCE and actor-critic.

The objective is J(θ) = E_{τ~π_θ}[Σ_t γ^t r_t]. The log-likelihood trick turns its gradient into
an expectation over trajectories the policy samples, with no model of the dynamics:

    ∇J(θ) = E_τ[ Σ_t ∇_θ log π_θ(a_t|s_t) · w_t ]

and one gradient step takes ĝ = (1/m) Σ_{i≤m} Σ_t ∇_θ log π_θ(a_t^i|s_t^i) w_t^i over a batch of
m episodes. The estimators differ in the weight w_t (`ESTIMATORS`, `policy_gradient_weights`):

- "return":       w_t = R(τ) = Σ_{t'} γ^{t'} r_{t'}, the whole trajectory's return (the score
  function estimator; `trajectory_returns`);
- "reward-to-go": w_t = G_t = Σ_{t'≥t} γ^{t'-t} r_{t'}: actions do not change past rewards
  (REINFORCE; `reward_to_go`);
- "baseline":     w_t = G_t − V_φ(s_t), the critic V_φ fit by regression on G_t; unbiased for
  any b(s) because E_{a~π}[∇ log π(a|s)] b(s) = 0;
- "actor-critic": w_t = Â_t, the n-step advantage (`n_step_targets`)

      Â_t^(n) = Σ_{k<n} γ^k r_{t+k} + γ^n V(s_{t+n}) − V(s_t)     (TD(0) at n = 1)

  or, without n, GAE(γ, λ) (`compute_gae`): Â_t = Σ_i (γλ)^i δ_{t+i}, δ_t = r_t + γ V(s_{t+1}) −
  V(s_t), which is TD(0) at λ = 0 and G_t − V(s_t) at λ = 1. The critic regresses on Â_t + V(s_t).

Episode ends: a termination ends the return (nothing follows); a time limit only truncates it,
so where a critic exists the tail is bootstrapped with V of the episode's true final state, as
PPO does. "return" and "reward-to-go" have no critic: a truncated episode's tail counts 0.

The policies are `imitation.policies.ActorCritic`: softmax for Discrete actions (score
φ(s,a) − E_{a'~π}[φ(s,a')] on linear features) and Gaussian for Box actions (score
(a − μ(s)) φ(s) / σ² for the mean); the score itself comes from autograd of log π.

`PolicyGradient` is the learner: one step collects a batch of complete episodes with π_θ (every
env copy runs episodes until the batch holds `batch_steps` steps, then finishes the one it is
in), takes one gradient step of the policy on −ĝ, and `value_steps` regression steps of the
critic on ½(V_φ(s_t) − target_t)². With `rollout_steps` (actor-critic only, as in A2C) a batch is
instead `rollout_steps` steps of every env copy: episodes run on across batches, and each piece
cut at the batch's end is bootstrapped with V of the state it reached, as a time limit is. The
critic then makes many small updates possible where whole episodes would allow few.

Options: w_t divided by its batch std (not centred, which would be a baseline), both learning
rates annealed linearly to 0, observations normalised by running statistics updated between
batches, rewards divided by the running std of the discounted return, an entropy bonus. Every
episode is reset with a seed drawn from the run's seed and its index, so a run resumed from a
checkpoint equals the run that was never stopped (an episode a checkpoint falls inside is
rebuilt by replaying its actions from that seed).
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass, field

import numpy as np
import torch

from imitation.algorithms.advantages import compute_gae
from imitation.algorithms.policy_gradient_config import WITH_CRITIC, PGConfig
from imitation.checkpoints import CheckpointData, CheckpointReader, CheckpointWriter, TrainingClock
from imitation.envs.make import make_env
from imitation.errors import ImitationError
from imitation.policies import RunningMeanStd, make_policy, require_flat_observations
from imitation.tensors import resolve_device

# ------------------------------------------------------------------------------------------------
# The formulas, as pure functions over a stream of steps (T, ...) whose episodes are contiguous;
# `next_values[t]` is V(s_{t+1}) of the state that followed step t: the next state in the stream,
# the true final state when step t was truncated, anything when it terminated.


def reward_to_go(
    rewards: torch.Tensor, next_values: torch.Tensor, terminated: torch.Tensor, truncated: torch.Tensor, *, gamma: float
) -> torch.Tensor:
    """G_t = r_t + γ G_{t+1} within an episode; at its last step G_t = r_t (terminated) or
    r_t + γ V(s_{t+1}) (truncated: the time limit cut a return that goes on)."""
    # The recursion runs in numpy: per-step torch calls would cost more than the network.
    r = rewards.detach().cpu().double().numpy()
    ends = (terminated | truncated).cpu().numpy()
    bootstrap = truncated.cpu().numpy() * next_values.detach().cpu().double().numpy()
    returns = np.zeros_like(r)
    running = np.zeros_like(r[0])
    for t in reversed(range(len(r))):
        running = r[t] + gamma * np.where(ends[t], bootstrap[t], running)
        returns[t] = running
    return torch.as_tensor(returns, dtype=rewards.dtype, device=rewards.device)


def trajectory_returns(
    rewards: torch.Tensor, terminated: torch.Tensor, truncated: torch.Tensor, *, gamma: float
) -> torch.Tensor:
    """R(τ) = Σ_t γ^t r_t of each step's episode, at every step of it (no bootstrap)."""
    from_each_step = reward_to_go(rewards, torch.zeros_like(rewards), terminated, truncated, gamma=gamma).cpu().numpy()
    ends = (terminated | truncated).cpu().numpy()
    returns = np.zeros_like(from_each_step)
    for t in range(len(returns)):
        starts = np.ones_like(ends[t]) if t == 0 else ends[t - 1]
        returns[t] = np.where(starts, from_each_step[t], returns[t - 1])
    return torch.as_tensor(returns, device=rewards.device)


def n_step_targets(
    rewards: torch.Tensor,
    next_values: torch.Tensor,
    terminated: torch.Tensor,
    truncated: torch.Tensor,
    *,
    gamma: float,
    n: int,
) -> torch.Tensor:
    """R_t^(n) = Σ_{k<m} γ^k r_{t+k} + γ^m V(s_{t+m}), m = min(n, steps to the episode's end):
    no bootstrap when the episode terminated within the n steps, V of its final state when it
    was truncated. Â_t^(n) = R_t^(n) − V(s_t). The stream's last step must end an episode."""
    length = rewards.shape[0]
    pad = (n, *rewards.shape[1:])
    padded_rewards = torch.cat([rewards, rewards.new_zeros(pad)])
    padded_next = torch.cat([next_values, next_values.new_zeros(pad)])
    # Past the stream's end, a terminated step: nothing there is added (the stream ends an episode).
    padded_ends = torch.cat([terminated | truncated, torch.ones(pad, dtype=torch.bool, device=rewards.device)])
    padded_truncated = torch.cat([truncated, torch.zeros(pad, dtype=torch.bool, device=rewards.device)])
    targets = torch.zeros_like(rewards)
    alive = torch.ones_like(rewards, dtype=torch.bool)  # the episode has not ended before step t+k
    discount = 1.0
    for k in range(n):
        window = slice(k, k + length)
        live = alive.float()
        targets = targets + live * discount * padded_rewards[window]
        ends_here = alive & padded_ends[window]
        targets = targets + (ends_here & padded_truncated[window]).float() * discount * gamma * padded_next[window]
        alive = alive & ~padded_ends[window]
        discount *= gamma
    # Still inside the episode after n steps: bootstrap from V(s_{t+n}), the state after step t+n-1.
    return targets + alive.float() * discount * padded_next[n - 1 : n - 1 + length]


def policy_gradient_weights(
    estimator: str,
    rewards: torch.Tensor,
    values: torch.Tensor,
    next_values: torch.Tensor,
    terminated: torch.Tensor,
    truncated: torch.Tensor,
    *,
    gamma: float,
    n_step: int | None = None,
    gae_lambda: float = 1.0,
) -> tuple[torch.Tensor, torch.Tensor]:
    """(w_t, the critic's regression target) of `estimator` (see the module docstring); the
    target is G_t for "baseline", Â_t + V(s_t) for "actor-critic", and unused (zeros) without a critic."""
    if estimator == "return":
        return trajectory_returns(rewards, terminated, truncated, gamma=gamma), torch.zeros_like(rewards)
    if estimator == "reward-to-go":
        no_critic = torch.zeros_like(rewards)
        return reward_to_go(rewards, no_critic, terminated, truncated, gamma=gamma), no_critic
    if estimator == "baseline":
        returns = reward_to_go(rewards, next_values, terminated, truncated, gamma=gamma)
        return returns - values, returns
    if n_step is not None:
        targets = n_step_targets(rewards, next_values, terminated, truncated, gamma=gamma, n=n_step)
        return targets - values, targets
    column = (rewards[:, None], values[:, None], next_values[:, None], terminated[:, None], truncated[:, None])
    advantages, targets = compute_gae(*column, gamma=gamma, gae_lambda=gae_lambda)
    return advantages[:, 0], targets[:, 0]


def running_returns(rewards: torch.Tensor, ends: torch.Tensor, *, gamma: float) -> torch.Tensor:
    """The discounted return so far, x_t = r_t + γ x_{t-1} (0 before an episode's first step):
    the quantity whose std the reward scaling divides by."""
    r, finished = rewards.cpu().double().numpy(), ends.cpu().numpy()
    out = np.zeros_like(r)
    running = 0.0
    for t in range(len(r)):
        running = r[t] + gamma * running
        out[t] = running
        if finished[t]:
            running = 0.0
    return torch.as_tensor(out, device=rewards.device)


def surrogate_loss(log_probs: torch.Tensor, weights: torch.Tensor, episodes: int) -> torch.Tensor:
    """−(1/m) Σ_i Σ_t log π_θ(a_t|s_t) w_t: its gradient is −ĝ (w_t held constant)."""
    return -(log_probs * weights.detach()).sum() / episodes


# ------------------------------------------------------------------------------------------------
# The learner


@dataclass
class Batch:
    """Complete episodes, one after another: encoded states (as the policy saw them), its
    actions, rewards (scaled if configured), the end flags, the encoded true final state of
    truncated steps (zeros elsewhere) and each episode's true return."""

    features: torch.Tensor
    actions: torch.Tensor
    rewards: torch.Tensor
    terminated: torch.Tensor
    truncated: torch.Tensor
    final_features: torch.Tensor
    episode_returns: list[float]  # of the episodes that ended in this batch
    pieces: int  # m: the episodes, or pieces of them cut by a rollout's end, in the batch


@dataclass
class _Episode:
    features: list[torch.Tensor] = field(default_factory=list)
    actions: list[torch.Tensor] = field(default_factory=list)
    rewards: list[float] = field(default_factory=list)
    final: torch.Tensor | None = None  # encoded true final state when truncated
    terminated: bool = False
    truncated: bool = False


class PolicyGradient:
    """The learner's state (π_θ and V_φ, their Adam optimisers, the normalisers, counters, recent
    returns) and its step: one batch of episodes, one policy-gradient step, the critic's fit."""

    name = "policy gradient"
    unit = "batch"

    def __init__(self, config: PGConfig) -> None:
        config.validate()
        torch.set_num_threads(config.threads)
        torch.manual_seed(config.seed)
        np.random.seed(config.seed)
        self.config = config
        self.device = device = resolve_device(config.device)
        self.envs = [make_env(config.env_id) for _ in range(config.n_envs)]
        policy = make_policy(
            self.envs[0].observation_space,
            self.envs[0].action_space,
            hidden_sizes=list(config.hidden_sizes),
            activation=config.activation,
            normalize_observations=config.normalize_observations,
            log_std_init=config.log_std_init,
        )
        self.policy = require_flat_observations(policy, "policy gradient").to(device)
        critic = {id(p) for p in [*self.policy.critic_trunk.parameters(), *self.policy.value_head.parameters()]}
        self.actor_parameters = [p for p in self.policy.parameters() if id(p) not in critic]
        self.critic_parameters = [p for p in self.policy.parameters() if id(p) in critic]
        self.optimizer = torch.optim.Adam(self.actor_parameters, lr=config.learning_rate)
        self.value_optimizer = torch.optim.Adam(self.critic_parameters, lr=config.value_learning_rate)
        # Rewards are divided by the running std of the discounted return (CleanRL's NormalizeReward,
        # its statistics updated once per batch): the critic's targets stay near unit scale.
        self.reward_scaler = RunningMeanStd(()) if config.normalize_rewards else None
        # Batches planned: the most there can be, since each holds at least steps_per_batch steps.
        self.total = -(-config.total_steps // config.steps_per_batch)
        # Each copy's episode in progress: its reset seed and the env actions since, so that a
        # checkpoint taken between rollouts can rebuild the env by replay (no pickled env state).
        self.observations: list[np.ndarray] | None = None
        self.episode_seeds = [0] * config.n_envs
        self.episode_actions: list[list[np.ndarray]] = [[] for _ in range(config.n_envs)]
        self.episode_rewards = [0.0] * config.n_envs
        self.batches = 0
        self.global_step = 0
        self.episodes = 0
        self.recent_returns: deque[float] = deque(maxlen=20)
        self.clock = TrainingClock()

    @property
    def completed(self) -> int:
        return self.batches

    @property
    def done(self) -> bool:
        return self.global_step >= self.config.total_steps or self.batches >= self.total

    def position(self) -> str:
        return f"batch {self.batches}, at step {self.global_step} of {self.config.total_steps}"

    def progress(self, row: dict[str, float]) -> dict[str, str]:
        return {"ret": f"{row['return']:.1f}", "steps": f"{row['step']:.0f}"}

    def _reset(self, copy: int) -> np.ndarray:
        # Episode k is reset with a seed of its own, so a batch depends only on θ and the RNGs.
        seed = int(np.random.SeedSequence([self.config.seed, self.episodes]).generate_state(1)[0])
        self.episodes += 1
        self.episode_seeds[copy], self.episode_actions[copy], self.episode_rewards[copy] = seed, [], 0.0
        observation, _ = self.envs[copy].reset(seed=seed)
        return observation

    def _replay(self) -> None:
        """Rebuild every copy's episode in progress from its reset seed and actions."""
        observations = []
        for env, seed, actions in zip(self.envs, self.episode_seeds, self.episode_actions, strict=True):
            observation, _ = env.reset(seed=seed)
            for action in actions:
                observation, *_ = env.step(action)
            observations.append(observation)
        self.observations = observations

    def collect(self) -> Batch:
        return self.collect_episodes() if self.config.rollout_steps is None else self.collect_rollout()

    def collect_rollout(self) -> Batch:
        """`rollout_steps` steps of every env copy, its episodes carried over from the last batch;
        a piece still running at the end is cut there, marked truncated and bootstrapped with V
        of the state it reached."""
        config, policy = self.config, self.policy
        assert config.rollout_steps is not None
        self.clock.start()
        if self.observations is None:
            self.observations = [self._reset(copy) for copy in range(config.n_envs)]
        pieces = [_Episode() for _ in range(config.n_envs)]
        finished: list[_Episode] = []
        returns: list[float] = []
        seen: list[torch.Tensor] = []
        steps = 0
        for _ in range(config.rollout_steps):
            features, actions, env_actions = self._act(np.stack(self.observations), steps, seen)
            for copy in range(config.n_envs):
                piece = pieces[copy]
                piece.features.append(features[copy])
                piece.actions.append(actions[copy])
                self.episode_actions[copy].append(env_actions[copy])
                steps += 1
                observation_next, reward, terminated, truncated = self._env_step(copy, env_actions[copy], steps)
                piece.rewards.append(reward)
                self.episode_rewards[copy] += reward
                if not (terminated or truncated):
                    self.observations[copy] = observation_next
                    continue
                self._end_piece(piece, observation_next, terminated, truncated)
                finished.append(piece)
                returns.append(self.episode_rewards[copy])
                pieces[copy] = _Episode()
                self.observations[copy] = self._reset(copy)
        # The cut pieces' final states, encoded in one call rather than one per copy.
        with torch.no_grad():
            reached = policy.encode(torch.as_tensor(np.stack(self.observations), device=self.device))
        for copy, piece in enumerate(pieces):
            if piece.rewards:
                piece.truncated, piece.final = True, reached[copy]
                finished.append(piece)
        policy.update_normalizer(torch.cat(seen))
        self.global_step += steps
        self.recent_returns.extend(returns)
        return self._batch(finished, returns)

    def _act(self, stacked: np.ndarray, steps: int, seen: list[torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor, np.ndarray]:
        """(encoded states, sampled actions, env actions) for a stack of raw observations (a
        reset's or the last step's), which join `seen` for the normaliser."""
        self._check_finite(stacked, "observation", steps)
        observation = torch.as_tensor(stacked, device=self.device)
        seen.append(observation)
        with torch.no_grad():
            features = self.policy.encode(observation)
            actions, _, _ = self.policy.sample(features)
        return features, actions, self.policy.to_env_action(actions)

    def _env_step(self, copy: int, action: np.ndarray, steps: int) -> tuple[np.ndarray, float, bool, bool]:
        """One step of env copy `copy` (the batch's step number `steps`): the next observation,
        reward, terminated and truncated, the first two checked finite."""
        observation_next, reward, terminated, truncated, _ = self.envs[copy].step(action)
        self._check_finite(np.asarray([reward], dtype=np.float64), "reward", steps)
        self._check_finite(np.asarray(observation_next)[None], "observation", steps)
        return observation_next, float(reward), bool(terminated), bool(truncated)

    def _end_piece(self, piece: _Episode, final: np.ndarray, terminated: bool, truncated: bool) -> None:
        """Mark how `piece` ended; a truncated one keeps its encoded final state for V's bootstrap."""
        if truncated and not terminated:
            with torch.no_grad():
                piece.final = self.policy.encode(torch.as_tensor(np.asarray(final)[None], device=self.device))[0]
        piece.terminated, piece.truncated = terminated, truncated and not terminated

    def collect_episodes(self) -> Batch:
        """Complete episodes with π_θ: each env copy starts a new episode while the batch holds
        fewer than `batch_steps` steps."""
        config, policy = self.config, self.policy
        self.clock.start()
        observations = {copy: self._reset(copy) for copy in range(config.n_envs)}
        running = {copy: _Episode() for copy in range(config.n_envs)}
        finished: list[_Episode] = []
        returns: list[float] = []
        steps = 0
        seen: list[torch.Tensor] = []  # raw observations, for the normaliser
        while observations:
            copies = list(observations)
            features, actions, env_actions = self._act(np.stack([observations[copy] for copy in copies]), steps, seen)
            for row, copy in enumerate(copies):
                episode = running[copy]
                episode.features.append(features[row])
                episode.actions.append(actions[row])
                steps += 1
                observation_next, reward, terminated, truncated = self._env_step(copy, env_actions[row], steps)
                episode.rewards.append(reward)
                if not (terminated or truncated):
                    observations[copy] = observation_next
                    continue
                self._end_piece(episode, observation_next, terminated, truncated)
                finished.append(episode)
                returns.append(float(sum(episode.rewards)))
                if steps < config.batch_steps:
                    observations[copy], running[copy] = self._reset(copy), _Episode()
                else:
                    del observations[copy]
        # The normaliser moves between batches only: within one, every state is encoded alike.
        policy.update_normalizer(torch.cat(seen))
        self.global_step += steps
        self.recent_returns.extend(returns)
        return self._batch(finished, returns)

    def _check_finite(self, array: np.ndarray, what: str, steps: int) -> None:
        """NaN or ±inf from the env stops training where it enters, naming the env step (of the
        run, counting from 1) that returned it; `steps` is the count within this batch."""
        if array.dtype.kind == "f" and not np.isfinite(array).all():
            raise ImitationError(
                f"{self.config.env_id}: the environment returned a non-finite {what} at env step "
                f"{self.global_step + steps}; policy gradient needs finite observations and rewards"
            )

    def _batch(self, episodes: list[_Episode], returns: list[float]) -> Batch:
        features = torch.stack([f for episode in episodes for f in episode.features])
        actions = torch.stack([a for episode in episodes for a in episode.actions])
        rewards = torch.tensor([r for episode in episodes for r in episode.rewards], dtype=torch.float32, device=self.device)
        terminated = torch.zeros(len(rewards), dtype=torch.bool, device=self.device)
        truncated = torch.zeros_like(terminated)
        final_features = torch.zeros_like(features)
        end = 0
        for episode in episodes:
            end += len(episode.rewards)
            terminated[end - 1], truncated[end - 1] = episode.terminated, episode.truncated
            if episode.final is not None:
                final_features[end - 1] = episode.final
        if self.reward_scaler is not None:
            self.reward_scaler.update(running_returns(rewards, terminated | truncated, gamma=self.config.gamma))
            rewards = torch.clamp(rewards / torch.sqrt(self.reward_scaler.var + 1e-8), -10.0, 10.0)
        return Batch(features, actions, rewards, terminated, truncated, final_features, returns, len(episodes))

    def weights(self, batch: Batch) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(w_t, the critic's targets, V(s_t)) for the batch, with the critic as it is now."""
        config = self.config
        with torch.no_grad():
            values = self.policy.value(batch.features)
            following = torch.cat([values[1:], values.new_zeros(1)])
            next_values = torch.where(batch.truncated, self.policy.value(batch.final_features), following)
        weights, targets = policy_gradient_weights(
            config.estimator,
            batch.rewards,
            values,
            next_values,
            batch.terminated,
            batch.truncated,
            gamma=config.gamma,
            n_step=config.n_step,
            gae_lambda=config.gae_lambda,
        )
        return weights, targets, values

    def policy_loss(self, batch: Batch, weights: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(−ĝ's surrogate, minus the entropy bonus; the mean entropy) on the batch."""
        if self.config.normalize_advantages and len(weights) > 1:
            weights = weights / (weights.std() + 1e-8)
        distribution = self.policy.distribution(batch.features)
        log_probs, entropy = self.policy.log_prob_and_entropy(distribution, batch.actions)
        loss = surrogate_loss(log_probs, weights, batch.pieces) - self.config.entropy_coef * entropy.mean()
        return loss, entropy.mean()

    def step(self) -> dict[str, float]:
        """One batch of episodes, one gradient step of π_θ, `value_steps` of V_φ's regression."""
        if self.config.anneal_lr:
            # By the steps taken, since batches differ in size: late steps fine-tune instead of undoing.
            remaining = max(0.0, 1.0 - self.global_step / self.config.total_steps)
            self.optimizer.param_groups[0]["lr"] = remaining * self.config.learning_rate
            self.value_optimizer.param_groups[0]["lr"] = remaining * self.config.value_learning_rate
        batch = self.collect()
        started = time.perf_counter()
        weights, targets, values = self.weights(batch)
        loss, entropy = self.policy_loss(batch, weights)
        if not torch.isfinite(loss):
            raise ImitationError(
                f"policy gradient batch {self.batches + 1}: the loss is {loss.item()} (diverged; try a lower --lr)"
            )
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        if self.config.max_grad_norm is not None:
            torch.nn.utils.clip_grad_norm_(self.actor_parameters, self.config.max_grad_norm)
        self.optimizer.step()
        value_loss = float("nan")
        if self.config.estimator in WITH_CRITIC:
            for _ in range(self.config.value_steps):
                fit = 0.5 * ((self.policy.value(batch.features) - targets) ** 2).mean()
                self.value_optimizer.zero_grad(set_to_none=True)
                fit.backward()
                self.value_optimizer.step()
                value_loss = fit.item()
        self.batches += 1
        explained = 1.0 - float(torch.var(targets - values) / (torch.var(targets) + 1e-8))
        return {
            "step": float(self.global_step),
            "return": float(np.mean(self.recent_returns)) if self.recent_returns else float("nan"),
            "batch_return": float(np.mean(batch.episode_returns)) if batch.episode_returns else float("nan"),
            "episodes": float(len(batch.episode_returns)),
            "policy_loss": loss.item(),
            "value_loss": value_loss,
            "explained_variance": explained if self.config.estimator in WITH_CRITIC else float("nan"),
            "entropy": entropy.item(),
            "learning_rate": self.optimizer.param_groups[0]["lr"],
            "steps_per_second": self.global_step / self.clock.seconds,
            "seconds_update": time.perf_counter() - started,
        }

    def close(self) -> None:
        for env in self.envs:
            env.close()

    def state_dict(self) -> CheckpointData:
        """Everything to continue after this batch: networks, both Adams, the normalisers, the
        counters (the episode counter seeds the next resets), recent returns and the RNGs; with
        `rollout_steps`, each episode in progress as its reset seed and actions, to replay."""
        in_progress = self.config.rollout_steps is not None and self.observations is not None
        checkpoint = CheckpointWriter(
            batch=self.batches,
            global_step=self.global_step,
            episodes=self.episodes,
            policy=self.policy.config.to_json(),
            recent_returns=list(self.recent_returns),
            episodes_in_progress=({"seeds": self.episode_seeds, "rewards": self.episode_rewards} if in_progress else None),
        )
        checkpoint.module("policy", self.policy.state_dict())
        checkpoint.optimizer(self.optimizer)
        checkpoint.optimizer(self.value_optimizer, "value_optimizer")
        checkpoint.rng()
        checkpoint.clock(self.clock)
        if self.reward_scaler is not None:
            checkpoint.module("reward_scaler", self.reward_scaler.state_dict())
        if in_progress:
            checkpoint.tensors |= {
                f"episode_actions.{copy}": torch.as_tensor(np.asarray(actions))
                for copy, actions in enumerate(self.episode_actions)
            }
        return checkpoint.data()

    def load_state_dict(self, checkpoint: CheckpointData) -> None:
        with CheckpointReader(checkpoint, "policy gradient") as saved:
            self.policy.load_state_dict(saved.module("policy"))
            saved.optimizer(self.optimizer)
            saved.optimizer(self.value_optimizer, "value_optimizer")
            if self.reward_scaler is not None:
                self.reward_scaler.load_state_dict(saved.module("reward_scaler"))
            saved.rng()
            self.recent_returns.extend(saved.state["recent_returns"])
            self.global_step, self.episodes = int(saved.state["global_step"]), int(saved.state["episodes"])
            saved.clock(self.clock)
            self.batches = saved.counter("batch", "next batch", 0, self.total)
            in_progress = saved.state.get("episodes_in_progress")
            if in_progress is not None:
                self.episode_seeds = [int(seed) for seed in in_progress["seeds"]]
                self.episode_rewards = [float(reward) for reward in in_progress["rewards"]]
                self.episode_actions = [
                    list(saved.tensors[f"episode_actions.{copy}"].numpy()) for copy in range(self.config.n_envs)
                ]
                self._replay()
