"""Apprenticeship learning by feature matching: Abbeel & Ng (2004), the projection method
(docs/THEORY.md, feature matching; the course notes §5.2).

The reward is taken linear in state features, r_w(s) = wᵀφ(s), so a policy's value is
wᵀμ(π) with its feature expectations

    μ(π) = E[Σ_{t=0}^{H} γ^t φ(s_t) | π],        μ_E the same average over the expert's demos,

and any policy (or mixture of policies) with ‖μ(π) - μ_E‖₂ ≤ ε earns within ε of the expert
under every reward with ‖w‖₂ ≤ 1. The projection method finds such a mixture:

    π^(0) random;  μ̄^(0) = μ^(0) = μ(π^(0))
    for i = 1, 2, …
        w^(i) = μ_E - μ̄^(i-1),   t^(i) = ‖w^(i)‖₂                    (`reward_weights`)
        π^(i) = the RL solver's policy for r = (w^(i)/‖w^(i)‖₂)ᵀφ,  μ^(i) = μ(π^(i))
        μ̄^(i) = μ̄^(i-1) + α^(i) (μ^(i) - μ̄^(i-1)),                  (`projection_step`)
            α^(i) = (μ^(i) - μ̄^(i-1))ᵀ(μ_E - μ̄^(i-1)) / ‖μ^(i) - μ̄^(i-1)‖²₂, clipped to [0, 1]
    until ‖μ_E - μ̄^(i)‖₂ ≤ ε ‖μ_E‖₂ (the tolerance is relative: features have any units).

μ̄^(i) is the orthogonal projection of μ_E onto the segment from μ̄^(i-1) to μ^(i); the clip
keeps it on the segment, so it stays a convex combination of μ^(0) … μ^(i), whose weights λ
follow the same update exactly (`mixture_weights`): λ ← ((1 - α) λ, α), Σ_j λ_j μ^(j) = μ̄^(i).
The mixture that picks π^(j) with probability λ_j at the start of an episode has feature
expectations μ̄, and its expected return is Σ_j λ_j R(π^(j)).
w is normalised to ‖w‖₂ = 1 as in the paper (only its direction changes the optimal policy).

Two RL solvers, one per kind of state:

- tabular MDPs (`TabularSolver`): μ(π) exact from the known dynamics, D_π(s) = Σ_t γ^t P(s_t = s)
  by the forward pass and μ(π) = Σ_s D_π(s) φ(s); π^(i) by value iteration, exact and
  time-indexed, V_H(s) = r(s), Q_t(s, a) = r(s) + γ Σ_{s'} P(s'|s, a) V_{t+1}(s'),
  V_t(s) = max_a Q_t(s, a), π_t(s) = argmax_a Q_t(s, a) (`optimal_policy`);
- Box observations (`PPOSolver`): μ(π) sampled, the mean over episodes of Σ_t γ^t φ(s_t), and
  π^(i) by the bundled PPO on r = wᵀφ(s), started from π^(i-1) (π^(0) is PPO's untrained
  policy). The features are the magnitudes of the bounded observation coordinates, scaled by
  their bounds, φ_k(s) = |s_k|/c_k for the coordinates k with finite bounds ±c_k (all
  coordinates, scaled by the demos' largest |s_k|, when none is bounded; `box_feature_scales`):
  wᵀφ can then pay for staying near the origin, symmetrically, as balancing tasks need. On
  CartPoleFixedHorizon-v0 that is the cart position, the pole angle and the failed indicator;
  the velocities, unbounded, are left out (scaled by the demos' range they would dominate μ).
  The features are not split by sign (relu(s_k), relu(-s_k)), so that w charges both sides of a
  coordinate alike: a sampled μ that saw one side only would leave the other free.

Each step of `Apprenticeship` is one iteration i (the first also evaluates π^(0)).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Protocol

import gymnasium as gym
import numpy as np
import torch

from imitation.algorithms.apprenticeship_config import ApprenticeshipConfig
from imitation.algorithms.ppo import PPO, PPOConfig
from imitation.checkpoints import CheckpointData, CheckpointReader, CheckpointWriter, TrainingClock, unprefixed
from imitation.envs.tabular import TabularMDP
from imitation.envs.tabular_planning import Dynamics, check_horizon, state_visitation
from imitation.policies import ActorCritic, PolicyConfig, SingleObservationPolicy
from imitation.rewards import RewardNet, make_reward_model
from imitation.seeding import seed_everything

_FIXED_POINT_TOLERANCE = 1e-10


def reward_weights(mu_expert: np.ndarray, mu_bar: np.ndarray) -> tuple[np.ndarray, float]:
    """w = μ_E - μ̄ normalised to ‖w‖₂ = 1, and t = ‖μ_E - μ̄‖₂ (w is 0 when t is)."""
    difference = mu_expert - mu_bar
    distance = float(np.linalg.norm(difference))
    return (difference / distance if distance > 0 else difference), distance


def projection_step(mu_bar: np.ndarray, mu: np.ndarray, mu_expert: np.ndarray) -> tuple[np.ndarray, float]:
    """(μ̄', α): μ_E projected onto the segment μ̄ → μ, α = (μ - μ̄)ᵀ(μ_E - μ̄) / ‖μ - μ̄‖² in [0, 1]
    (0 when μ = μ̄: the new policy adds nothing)."""
    step = mu - mu_bar
    squared = float(step @ step)
    alpha = float(np.clip(step @ (mu_expert - mu_bar) / squared, 0.0, 1.0)) if squared > 0 else 0.0
    return mu_bar + alpha * step, alpha


def mixture_weights(lambdas: np.ndarray, alpha: float) -> np.ndarray:
    """λ after μ̄' = (1 - α) μ̄ + α μ^(i): the old weights scaled by 1 - α, the new policy's α."""
    return np.append((1.0 - alpha) * lambdas, alpha)


def discounted_feature_sum(features: np.ndarray, discount: float) -> np.ndarray:
    """Σ_t γ^t φ(s_t) over one episode's states (rows of `features`)."""
    return discount ** np.arange(len(features)) @ features


def optimal_policy(dynamics: Dynamics, reward: np.ndarray, *, horizon: int | None, discount: float) -> np.ndarray:
    """Value iteration: the deterministic optimal policy for r(s) as one-hot π_t(a|s), (H, S, A)
    time-indexed for a finite horizon, (S, A) stationary (to a fixed point) for H = None; ties go
    to the lowest action."""
    check_horizon(horizon, discount)
    reward = reward.astype(np.float64)
    eye = np.eye(dynamics.n_actions)
    if horizon is None:
        values = reward / (1.0 - discount)
        for _ in range(100_000):
            q = reward[:, None] + discount * dynamics.expectation(values)
            updated = q.max(axis=1)
            converged = np.abs(updated - values).max() < _FIXED_POINT_TOLERANCE
            values = updated
            if converged:
                break
        return eye[q.argmax(axis=1)]
    policy = np.empty((horizon, dynamics.n_states, dynamics.n_actions))
    values = reward
    for t in reversed(range(horizon)):
        q = reward[:, None] + discount * dynamics.expectation(values)
        policy[t] = eye[q.argmax(axis=1)]
        values = q.max(axis=1)
    return policy


def box_feature_scales(space: gym.spaces.Box, observations: np.ndarray) -> np.ndarray:
    """c_k = max(|low_k|, |high_k|) for the coordinates with both bounds finite, ∞ (no feature)
    for the others; when no coordinate is bounded, every c_k is the largest |s_k| of
    `observations` (at least 1e-3)."""
    low, high = space.low.reshape(-1).astype(np.float64), space.high.reshape(-1).astype(np.float64)
    bound = np.maximum(np.abs(low), np.abs(high))
    if np.isfinite(bound).any():
        return np.where(np.isfinite(bound), bound, np.inf)
    seen = np.abs(observations.reshape(len(observations), -1)).max(axis=0) if len(observations) else np.zeros_like(bound)
    return np.maximum(seen, 1e-3)


def box_feature_reward(observation_space: gym.spaces.Box, action_space: gym.Space, scales: np.ndarray) -> RewardNet:
    """r(s) = wᵀφ(s), φ_k(s) = |s_k|/c_k over the coordinates k of finite scale, as a RewardNet: a
    fixed first layer relu([s_K/c_K; -s_K/c_K]) (|s| = relu(s) + relu(-s)), then (w, w) (zero)."""
    used = np.flatnonzero(np.isfinite(scales))
    model = make_reward_model(observation_space, action_space, hidden_sizes=[2 * len(used)], activation="relu")
    first, last = model.net[0], model.net[-1]
    assert isinstance(first, torch.nn.Linear) and isinstance(last, torch.nn.Linear)  # built just above
    selection = torch.zeros((len(used), len(scales)))
    selection[torch.arange(len(used)), torch.as_tensor(used)] = torch.as_tensor(1.0 / scales[used], dtype=torch.float32)
    with torch.no_grad():
        first.weight.copy_(torch.cat([selection, -selection]))
        first.bias.zero_()
        last.weight.zero_()
        last.bias.zero_()
    return model


def tabular_feature_reward(observation_space: gym.Space, action_space: gym.Space, features: np.ndarray) -> RewardNet:
    """r(s) = wᵀφ(s) as a linear RewardNet on the MDP's feature table (w zero)."""
    model = make_reward_model(observation_space, action_space, feature_table=features, hidden_sizes=[])
    set_reward_weights(model, np.zeros(features.shape[1]))
    return model


def set_reward_weights(model: RewardNet, weights: np.ndarray) -> None:
    """The last layer of a feature reward ← w, bias 0: w itself on a tabular one
    (`tabular_feature_reward`), (w, w) on a Box one (`box_feature_reward`), whose hidden units
    relu(s_k/c_k) and relu(-s_k/c_k) sum to φ_k(s) = |s_k|/c_k."""
    last = model.net[-1]
    assert isinstance(last, torch.nn.Linear)  # every RewardNet ends in one
    with torch.no_grad():
        last.weight.copy_(
            torch.as_tensor(np.tile(weights, last.in_features // len(weights)), dtype=torch.float32).reshape(1, -1)
        )
        last.bias.zero_()


def reward_features(model: RewardNet, observations: np.ndarray) -> np.ndarray:
    """φ(s) = (|s_k|/c_k)_k of a Box feature reward (`box_feature_reward`) for each row of
    `observations`: the sum of the two halves of its hidden layer."""
    with torch.no_grad():
        states = torch.as_tensor(observations)
        hidden = model.net[:-1](model.inputs(states, states, states)).double().numpy()
    half = hidden.shape[1] // 2
    return hidden[:, :half] + hidden[:, half:]


# ------------------------------------------------------------------------------------------------
# The RL solvers


class Solver(Protocol):
    """Finds π^(i) for a reward's weights and measures μ(π^(i)); keeps the policies it found."""

    def random_policy(self) -> np.ndarray: ...  # adds π^(0), returns μ(π^(0))

    def solve(self, weights: np.ndarray) -> np.ndarray: ...  # adds π^(i) for r = wᵀφ, returns μ(π^(i))

    def state_dict(self) -> CheckpointData: ...

    def load_state_dict(self, checkpoint: CheckpointData) -> None: ...


class TabularSolver:
    """Exact: the uniform random π^(0), value iteration, μ(π) from the known dynamics."""

    def __init__(self, mdp: TabularMDP, discount: float) -> None:
        check_horizon(mdp.horizon, discount)
        self.mdp, self.discount = mdp, discount
        self.dynamics = Dynamics.of(mdp.transition)
        self.policies: list[np.ndarray] = []

    def feature_expectations(self, policy: np.ndarray) -> np.ndarray:
        occupancy = state_visitation(self.dynamics, self.mdp.initial, policy, horizon=self.mdp.horizon, discount=self.discount)
        return occupancy @ self.mdp.features

    def _shape(self) -> tuple[int, ...]:
        mdp = self.mdp
        return (mdp.n_states, mdp.n_actions) if mdp.horizon is None else (mdp.horizon, mdp.n_states, mdp.n_actions)

    def random_policy(self) -> np.ndarray:
        self.policies.append(np.full(self._shape(), 1.0 / self.mdp.n_actions))
        return self.feature_expectations(self.policies[-1])

    def solve(self, weights: np.ndarray) -> np.ndarray:
        reward = self.mdp.features @ weights
        self.policies.append(optimal_policy(self.dynamics, reward, horizon=self.mdp.horizon, discount=self.discount))
        return self.feature_expectations(self.policies[-1])

    def state_dict(self) -> CheckpointData:
        stacked = torch.as_tensor(np.stack(self.policies)) if self.policies else torch.zeros((0, *self._shape()))
        return {"policies": stacked}, {}

    def load_state_dict(self, checkpoint: CheckpointData) -> None:
        tensors, _ = checkpoint
        policies = tensors["policies"].double().numpy()
        if policies.shape[1:] != self._shape():
            raise ValueError(f"policies of shape {tuple(policies.shape[1:])}, the MDP's are {self._shape()}")
        self.policies = list(policies)


class PPOSolver:
    """Sampled: PPO on r = wᵀφ(s) (each iteration `solver_steps` steps from the previous policy,
    seeded by the iteration), μ(π) the mean of Σ_t γ^t φ(s_t) over `episodes` episodes of the
    policy acting deterministically (as `eval policy` plays it)."""

    def __init__(self, ppo_config: PPOConfig, reward: RewardNet, config: ApprenticeshipConfig) -> None:
        self.ppo_config, self.reward, self.config = ppo_config, reward, config
        self.policies: list[ActorCritic] = []
        self.steps = 0  # PPO steps taken in all

    def _ppo(self, seed: int) -> PPO:
        return PPO(replace(self.ppo_config, seed=seed, total_steps=self.config.solver_steps), reward=self.reward)

    def feature_expectations(self, policy: ActorCritic, seed: int) -> np.ndarray:
        from imitation.envs.make import make_env

        actor = SingleObservationPolicy(policy)
        sums = []
        env = make_env(self.ppo_config.env_id)
        try:
            for episode in range(self.config.episodes):
                observation, _ = env.reset(seed=seed + episode)
                observations, done = [observation], False
                while not done:
                    observation, _, terminated, truncated, _ = env.step(actor(observation))
                    observations.append(observation)
                    done = terminated or truncated
                features = reward_features(self.reward, np.asarray(observations, dtype=np.float32))
                sums.append(discounted_feature_sum(features, self.config.discount))
        finally:
            env.close()
        return np.mean(sums, axis=0)

    def _seed(self) -> int:
        """Iteration i's seed: the run's, offset so that no two iterations share one."""
        return self.config.seed + 1000 * len(self.policies)

    def random_policy(self) -> np.ndarray:
        seed = self._seed()
        seed_everything(seed)
        ppo = self._ppo(seed)
        ppo.close()
        self.policies.append(ppo.policy.cpu().eval())
        return self.feature_expectations(self.policies[-1], seed)

    def solve(self, weights: np.ndarray) -> np.ndarray:
        seed = self._seed()
        seed_everything(seed)
        set_reward_weights(self.reward, weights)
        ppo = self._ppo(seed)
        try:
            ppo.policy.load_state_dict(self.policies[-1].state_dict())
            while not ppo.done:
                ppo.step()
        finally:
            ppo.close()
        self.steps += ppo.global_step
        self.policies.append(ppo.policy.cpu().eval())
        return self.feature_expectations(self.policies[-1], seed)

    def state_dict(self) -> CheckpointData:
        config = self.policies[0].config.to_json() if self.policies else None
        checkpoint = CheckpointWriter(policies=len(self.policies), policy=config, steps=self.steps)
        for index, policy in enumerate(self.policies):
            checkpoint.module(f"policy{index}", policy.state_dict())
        return checkpoint.data()

    def load_state_dict(self, checkpoint: CheckpointData) -> None:
        tensors, state = checkpoint
        self.policies = []
        for index in range(int(state["policies"])):
            policy = ActorCritic(PolicyConfig.from_json(state["policy"]))
            policy.load_state_dict(unprefixed(f"policy{index}", tensors))
            self.policies.append(policy.eval())
        self.steps = int(state["steps"])


# ------------------------------------------------------------------------------------------------
# The learner


class Apprenticeship:
    """The projection method over a `Solver`: μ^(j), w^(i), λ and μ̄ as the module's docstring
    defines them, one iteration per step, until ‖μ_E - μ̄‖₂ ≤ tolerance · ‖μ_E‖₂, the iterations
    run out, or a new policy's μ equals μ̄ (no direction left to move in: `stalled`)."""

    name = "apprenticeship learning"
    unit = "iteration"

    def __init__(self, solver: Solver, mu_expert: np.ndarray, config: ApprenticeshipConfig) -> None:
        config.validate()
        self.solver, self.mu_expert, self.config = solver, mu_expert.astype(np.float64), config
        self.total = config.iterations
        self.mus: np.ndarray = np.zeros((0, len(mu_expert)))  # μ^(0), μ^(1), …
        self.weights: np.ndarray = np.zeros((0, len(mu_expert)))  # unit w^(1), w^(2), …
        self.lambdas: np.ndarray = np.zeros(0)
        self.mu_bar: np.ndarray = np.zeros(len(mu_expert))
        self.iterations = 0
        self.converged = False
        self.stalled = False
        self.clock = TrainingClock()

    @property
    def completed(self) -> int:
        return self.iterations

    @property
    def done(self) -> bool:
        return self.converged or self.stalled or self.iterations >= self.total

    def position(self) -> str:
        return f"iteration {self.iterations} of {self.total}"

    def progress(self, row: dict[str, float]) -> dict[str, str]:
        return {"distance": f"{row['relative_distance']:.3f}", "alpha": f"{row['alpha']:.2f}"}

    @property
    def distance(self) -> float:
        """‖μ_E - μ̄‖₂ now."""
        return float(np.linalg.norm(self.mu_expert - self.mu_bar))

    def step(self) -> dict[str, float]:
        self.clock.start()
        if len(self.mus) == 0:
            self.mus = self.solver.random_policy()[None]
            self.mu_bar, self.lambdas = self.mus[0].copy(), np.ones(1)
        weights, margin = reward_weights(self.mu_expert, self.mu_bar)
        mu = self.solver.solve(weights)
        self.stalled = bool(np.array_equal(mu, self.mu_bar))
        self.mu_bar, alpha = projection_step(self.mu_bar, mu, self.mu_expert)
        self.lambdas = mixture_weights(self.lambdas, alpha)
        self.mus = np.vstack([self.mus, mu])
        self.weights = np.vstack([self.weights, weights])
        self.iterations += 1
        scale = float(np.linalg.norm(self.mu_expert))
        self.converged = self.distance <= self.config.tolerance * scale
        return {
            "iteration": float(self.iterations),
            "distance": self.distance,
            "relative_distance": self.distance / scale if scale > 0 else self.distance,
            "margin": margin,
            "alpha": alpha,
            "policy_distance": float(np.linalg.norm(mu - self.mu_expert)),
        }

    def closest(self) -> int:
        """The member j ≥ 1 (a solver's policy, not the random π^(0)) with μ^(j) nearest μ_E."""
        return 1 + int(np.argmin(np.linalg.norm(self.mus[1:] - self.mu_expert, axis=1)))

    def state_dict(self) -> CheckpointData:
        """μ^(j), w^(i), λ, μ̄ and the solver's policies (float64: the mixture's weights are kept exact)."""
        checkpoint = CheckpointWriter(
            iteration=self.iterations + 1,
            # Why the run stopped before its budget, if it did: a run resumed after its last step
            # (from a Ctrl-C in its final evaluation) must not iterate on.
            converged=self.converged,
            stalled=self.stalled,
        )
        checkpoint.clock(self.clock)
        checkpoint.tensors |= {
            "mus": torch.as_tensor(self.mus),
            "weights": torch.as_tensor(self.weights),
            "lambdas": torch.as_tensor(self.lambdas),
            "mu_bar": torch.as_tensor(self.mu_bar),
        }
        solver_tensors, checkpoint.state["solver"] = self.solver.state_dict()
        checkpoint.module("solver", solver_tensors)
        return checkpoint.data()

    def load_state_dict(self, checkpoint: CheckpointData) -> None:
        with CheckpointReader(checkpoint, "apprenticeship learning") as saved:
            self.iterations = saved.counter("iteration", "next iteration", 1, self.total + 1) - 1
            self.mus = saved.tensors["mus"].double().numpy().reshape(self.iterations + 1, len(self.mu_expert))
            self.weights = saved.tensors["weights"].double().numpy().reshape(self.iterations, len(self.mu_expert))
            self.lambdas = saved.tensors["lambdas"].double().numpy().reshape(self.iterations + 1)
            self.mu_bar = saved.tensors["mu_bar"].double().numpy().reshape(len(self.mu_expert))
            self.solver.load_state_dict((saved.module("solver"), saved.state["solver"]))
            saved.clock(self.clock)
            self.converged, self.stalled = bool(saved.state.get("converged", False)), bool(saved.state.get("stalled", False))


def mixture_summary(learner: Apprenticeship) -> dict[str, Any]:
    """What a run records of the mixture: λ, μ^(j), w^(i), μ̄ and μ_E, as lists."""
    return {
        "lambdas": learner.lambdas.tolist(),
        "feature_expectations": learner.mus.tolist(),
        "reward_weights": learner.weights.tolist(),
        "mixture_feature_expectations": learner.mu_bar.tolist(),
        "expert_feature_expectations": learner.mu_expert.tolist(),
    }
