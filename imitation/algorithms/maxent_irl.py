"""Tabular maximum-entropy IRL (theory notes §5.3): Ziebart et al. 2008 and its causal variant.

The model: a trajectory τ = (s_0, a_0, …, s_H) of an MDP with known dynamics P is scored by
its discounted reward R_θ(τ) = Σ_{t=0}^{H} γ^t r_θ(s_t) over all H + 1 states it visits, with
r_θ(s) = wᵀx(s) (linear in the features x) or an MLP on x(s). Learning maximises the demos'
likelihood, whose gradient (notes §5.3.3) is

    ∇L(θ) = Σ_s (D̃(s) - D_θ(s)) ∇r_θ(s),     for linear r:  μ̃ - Σ_s D_θ(s) x(s)

with D̃ the demos' (discounted) state visitation frequencies and D_θ those of the policy that
is soft-optimal for r_θ. Each iteration computes D_θ in two passes:

- backward pass (soft value iteration), V_{H}(s) = r(s), for t = H-1 … 0:
      mce    (maximum *causal* entropy, Ziebart 2010; exact for stochastic dynamics):
             Q_t(s, a) = r(s) + γ Σ_{s'} P(s'|s, a) V_{t+1}(s')
      maxent (Ziebart 2008; exact for deterministic dynamics, where both coincide):
             Q_t(s, a) = r(s) + γ log Σ_{s'} P(s'|s, a) exp V_{t+1}(s')
      V_t(s) = log Σ_a exp Q_t(s, a),   π_t(a|s) = exp(Q_t(s, a) - V_t(s))
- forward pass: D_0 = ρ₀, D_{t+1}(s') = Σ_{s, a} D_t(s) π_t(a|s) P(s'|s, a), and
  D_θ(s) = Σ_{t=0}^{H} γ^t D_t(s), which sums to H + 1 when γ = 1.

With H = None the MDP is infinite-horizon and discounted (γ < 1 is then required): V and π are
stationary, found by iterating the backward step to a fixed point, and D_θ sums to 1/(1-γ).

Learning runs Adam on r_θ's parameters; with `checkpoints` it saves them, Adam's state and the
logged rows every tenth of the iterations and on Ctrl-C, and resumes from them exactly (nothing
in an iteration is random).

Large MDPs store their dynamics sparsely, as K successors per (s, a): gridworlds have K ≤ 3, so
both passes cost O(S·A·K) per step instead of the O(S²·A) of a dense P; small ones use dense
matrix products, which cost fewer numpy calls.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable, Iterable

import numpy as np
import torch

from imitation.checkpoints import (
    CheckpointData,
    Checkpointing,
    StopAtBoundary,
    TrainingInterrupted,
    checked_counter,
    floats,
    optimizer_checkpoint,
    prefixed,
    restore_optimizer,
    snapshot,
    unprefixed,
)
from imitation.data.types import Episode, Transitions
from imitation.envs.tabular import TabularMDP
from imitation.errors import ImitationError
from imitation.rewards import RewardNet

METHODS = ("maxent", "mce")
_FIXED_POINT_TOLERANCE = 1e-12


def _logsumexp_rows(values: np.ndarray) -> np.ndarray:
    """log Σ_a exp q(s, a) per row. On small arrays one pairwise `logaddexp` reduction is cheaper
    than the five numpy calls of the max-shifted form; on large ones it is the slower (the effect
    on a whole iteration shows in bench/irl.py's two MDP sizes)."""
    if values.size <= 4096:
        return np.logaddexp.reduce(values, axis=1)
    top = values.max(axis=1)
    return np.log(np.exp(values - top[:, None]).sum(axis=1)) + top


def _logsumexp(values: np.ndarray, axis: int) -> np.ndarray:
    top = values.max(axis=axis, keepdims=True)
    return (top + np.log(np.exp(values - top).sum(axis=axis, keepdims=True))).squeeze(axis)


class Dynamics:
    """P(s'|s, a), with the three operations the passes need."""

    n_states: int
    n_actions: int
    is_deterministic: bool

    def expectation(self, values: np.ndarray) -> np.ndarray:
        """Σ_{s'} P(s'|s, a) v(s') for every (s, a): shape (S, A)."""
        raise NotImplementedError

    def log_expectation_of_exp(self, values: np.ndarray) -> np.ndarray:
        """log Σ_{s'} P(s'|s, a) exp v(s') for every (s, a): shape (S, A)."""
        raise NotImplementedError

    def propagate(self, state_action_mass: np.ndarray) -> np.ndarray:
        """Σ_{s, a} m(s, a) P(s'|s, a) for every s': shape (S,)."""
        raise NotImplementedError

    @staticmethod
    def of(transition: np.ndarray) -> Dynamics:
        """Dense matrix products for small MDPs, where numpy's per-call cost dominates; sparse
        gathers when each (s, a) reaches a small fraction of the states."""
        n_states = transition.shape[0]
        width = int((transition > 0).sum(-1).max())
        if n_states <= 256 or width > n_states // 8:
            return DenseDynamics(transition)
        return SparseDynamics(transition, width)


class DenseDynamics(Dynamics):
    def __init__(self, transition: np.ndarray) -> None:
        self.n_states, self.n_actions, _ = transition.shape
        self.flat = np.ascontiguousarray(transition.reshape(-1, self.n_states), dtype=np.float64)
        self.is_deterministic = bool(np.all(transition.max(-1) == 1.0))

    def expectation(self, values: np.ndarray) -> np.ndarray:
        return (self.flat @ values).reshape(self.n_states, self.n_actions)

    def log_expectation_of_exp(self, values: np.ndarray) -> np.ndarray:
        with np.errstate(divide="ignore"):
            return _logsumexp(np.log(self.flat) + values, axis=1).reshape(self.n_states, self.n_actions)

    def propagate(self, state_action_mass: np.ndarray) -> np.ndarray:
        return state_action_mass.reshape(-1) @ self.flat


class SparseDynamics(Dynamics):
    """P[s, a, ·] as `successors[s, a, k]` with `probabilities[s, a, k]`, k < width (zero-padded)."""

    def __init__(self, transition: np.ndarray, width: int) -> None:
        self.n_states, self.n_actions, _ = transition.shape
        # The `width` largest entries of each row hold all of its non-zero mass.
        self.successors = np.argsort(-transition, axis=-1, kind="stable")[..., :width]
        self.probabilities = np.take_along_axis(transition, self.successors, axis=-1)
        self.is_deterministic = bool(np.all(self.probabilities.max(-1) == 1.0))

    def expectation(self, values: np.ndarray) -> np.ndarray:
        return (self.probabilities * values[self.successors]).sum(-1)

    def log_expectation_of_exp(self, values: np.ndarray) -> np.ndarray:
        with np.errstate(divide="ignore"):
            return _logsumexp(np.log(self.probabilities) + values[self.successors], axis=-1)

    def propagate(self, state_action_mass: np.ndarray) -> np.ndarray:
        weights = (state_action_mass[..., None] * self.probabilities).reshape(-1)
        return np.bincount(self.successors.reshape(-1), weights=weights, minlength=self.n_states)


def _check_horizon(horizon: int | None, discount: float) -> None:
    if not 0.0 < discount <= 1.0:
        raise ImitationError(f"discount must be in (0, 1], got {discount}")
    if horizon is None and discount >= 1.0:
        raise ImitationError("an infinite horizon needs a discount below 1 (the undiscounted occupancy is infinite); give a horizon or --discount < 1")
    if horizon is not None and horizon < 1:
        raise ImitationError(f"horizon must be at least 1, got {horizon}")


def soft_value_iteration(
    dynamics: Dynamics, reward: np.ndarray, *, horizon: int | None, discount: float, method: str = "mce"
) -> tuple[np.ndarray, np.ndarray]:
    """The backward pass: (π, V_0) with π of shape (H, S, A), or (S, A) when H is None."""
    _check_horizon(horizon, discount)
    if method not in METHODS:
        raise ImitationError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    backup = dynamics.expectation if method == "mce" else dynamics.log_expectation_of_exp

    def q_values(next_values: np.ndarray) -> np.ndarray:
        return reward[:, None] + discount * backup(next_values)

    if horizon is None:
        values = reward / (1.0 - discount)
        for _ in range(100_000):
            q = q_values(values)
            updated = _logsumexp_rows(q)
            converged = np.abs(updated - values).max() < _FIXED_POINT_TOLERANCE
            values = updated
            if converged:
                break
        return np.exp(q - values[:, None]), values

    # The hot loop of every IRL iteration: written as few numpy calls as possible.
    q = np.empty((horizon, dynamics.n_states, dynamics.n_actions))
    state_values = np.empty((horizon, dynamics.n_states))
    reward_column = reward.astype(np.float64)[:, None]
    values = reward_column[:, 0]
    for t in reversed(range(horizon)):
        q_t = q[t]
        np.multiply(backup(values), discount, out=q_t)
        q_t += reward_column
        values = state_values[t] = _logsumexp_rows(q_t)
    return np.exp(q - state_values[..., None]), values


def visits_by_time(dynamics: Dynamics, initial: np.ndarray, policy: np.ndarray) -> np.ndarray:
    """D_t(s) for t = 0 … H under a time-indexed policy of shape (H, S, A): (H + 1, S)."""
    visits = np.empty((len(policy) + 1, dynamics.n_states))
    visits[0] = initial
    for t, step_policy in enumerate(policy):
        visits[t + 1] = dynamics.propagate(visits[t][:, None] * step_policy)
    return visits


def state_visitation(
    dynamics: Dynamics, initial: np.ndarray, policy: np.ndarray, *, horizon: int | None, discount: float
) -> np.ndarray:
    """The forward pass: D_θ(s) = Σ_t γ^t D_t(s) for a time-indexed (H, S, A) or stationary (S, A) policy."""
    _check_horizon(horizon, discount)
    if horizon is not None:
        return discount ** np.arange(horizon + 1) @ visits_by_time(dynamics, initial, policy)
    visits = initial.astype(np.float64)
    occupancy = visits.copy()
    weight = 1.0
    while weight >= _FIXED_POINT_TOLERANCE:
        visits = dynamics.propagate(visits[:, None] * policy)
        weight *= discount
        occupancy += weight * visits
    return occupancy


def expected_return(dynamics: Dynamics, mdp: TabularMDP, policy: np.ndarray) -> float:
    """The env's expected return Σ_{t<H} E[r(s_t)] under a time-indexed policy: what TabularEnv
    pays, for the H states an action is taken in (the final state s_H earns nothing)."""
    return float(visits_by_time(dynamics, mdp.initial, policy)[:-1].sum(0) @ mdp.reward)


# ------------------------------------------------------------------------------------------------
# The demos' side: D̃ from episodes, transitions or a loader.


def demo_visitation(
    demos: Iterable[Episode] | Transitions, *, n_states: int, horizon: int | None, discount: float
) -> np.ndarray:
    """D̃(s) = (1/m) Σ_j Σ_{t=0}^{T_j} γ^t 1[s_t^j = s] over m demo episodes (each of H steps when
    the horizon is finite, so its H + 1 observations are all counted).

    Transitions carry no time index, so they are accepted for γ = 1 only: every observation, and
    the final next-observation of each episode, counts once, divided by the number of episodes."""
    _check_horizon(horizon, discount)
    if isinstance(demos, Transitions):
        return _transitions_visitation(demos, n_states=n_states, discount=discount)
    occupancy = np.zeros(n_states)
    count = 0
    for index, episode in enumerate(demos):
        states = np.asarray(episode.observations).astype(np.int64).reshape(-1)
        if horizon is not None and len(states) != horizon + 1:
            raise ImitationError(f"demo episode {index} has {len(states) - 1} steps, but the MDP's horizon is {horizon}")
        _check_states(states, n_states, f"demo episode {index}")
        np.add.at(occupancy, states, discount ** np.arange(len(states)))
        count += 1
    if count == 0:
        raise ImitationError("no demo episodes")
    return occupancy / count


def _transitions_visitation(transitions: Transitions, *, n_states: int, discount: float) -> np.ndarray:
    if discount != 1.0:
        raise ImitationError("flat transitions have no time index: give whole episodes for a discount below 1")
    if transitions.next_observations is None:
        raise ImitationError("transitions need next observations to count each episode's final state")
    states = np.asarray(transitions.observations).astype(np.int64).reshape(-1)
    ends = np.asarray(transitions.terminated) | np.asarray(transitions.truncated)
    finals = np.asarray(transitions.next_observations).astype(np.int64).reshape(-1)[ends]
    if not ends.any():
        raise ImitationError("transitions hold no complete episode")
    _check_states(np.concatenate([states, finals]), n_states, "transitions")
    return np.bincount(np.concatenate([states, finals]), minlength=n_states) / ends.sum()


def _check_states(states: np.ndarray, n_states: int, where: str) -> None:
    if states.size and (states.min() < 0 or states.max() >= n_states):
        raise ImitationError(f"{where}: observation {int(states.max() if states.max() >= n_states else states.min())} is not a state of an MDP with {n_states} states")


# ------------------------------------------------------------------------------------------------
# Learning


@dataclass(kw_only=True)
class MaxEntIRLConfig:
    method: str = "mce"
    discount: float = 1.0
    iterations: int = 2000
    learning_rate: float = 0.05
    tolerance: float = 1e-4
    hidden_sizes: list[int] = field(default_factory=list)
    seed: int = 0

    def validate(self) -> None:
        if self.method not in METHODS:
            raise ImitationError(f"--method must be one of {', '.join(METHODS)} for tabular IRL, got {self.method!r}")
        if self.iterations < 1:
            raise ImitationError(f"iterations must be at least 1, got {self.iterations}")
        if not 0 < self.learning_rate < 1e30:  # NaN fails too; from ~1e37 Adam's step overflows float32
            raise ImitationError(f"--lr must be a positive number below 1e30, got {self.learning_rate}")


@dataclass
class MaxEntIRLResult:
    reward_model: RewardNet
    policy: np.ndarray
    occupancy: np.ndarray
    history: list[dict[str, float]]
    seconds: float


def all_state_rewards(model: RewardNet, n_states: int) -> torch.Tensor:
    """r_θ(s) for every state s (the model maps a state index to its features itself)."""
    states = torch.arange(n_states)
    return model(states, states, states)


def train_maxent_irl(
    mdp: TabularMDP,
    demo_occupancy: np.ndarray,
    reward_model: RewardNet,
    config: MaxEntIRLConfig,
    *,
    log: Callable[[dict[str, float]], None] | None = None,
    checkpoints: Checkpointing | None = None,
) -> MaxEntIRLResult:
    """Gradient ascent on the demos' likelihood with Adam, until the learned visitation matches
    D̃ to `tolerance` (L∞) or `iterations` run out.

    With `checkpoints`, a checkpoint is saved every tenth of the iterations (by default), Ctrl-C
    stops after the current iteration with a checkpoint saved (TrainingInterrupted), and a run
    given `checkpoints.resume` continues from one exactly as if it had not stopped."""
    config.validate()
    horizon = mdp.horizon
    _check_horizon(horizon, config.discount)
    if demo_occupancy.shape != (mdp.n_states,):
        raise ImitationError(f"demo occupancy has shape {demo_occupancy.shape}, the MDP has {mdp.n_states} states")
    torch.manual_seed(config.seed)
    dynamics = Dynamics.of(mdp.transition)
    if config.method == "maxent" and not dynamics.is_deterministic:
        raise ImitationError("--method maxent (Ziebart 2008) assumes deterministic dynamics and this MDP's are stochastic; use --method mce")
    # fused: one kernel for the whole step, fewer calls on the small tabular reward
    optimizer = torch.optim.Adam(reward_model.parameters(), lr=config.learning_rate, fused=True)
    target = torch.as_tensor(demo_occupancy)
    history: list[dict[str, float]] = []
    started = time.perf_counter()
    first_iteration = 1
    if checkpoints is not None and checkpoints.resume is not None:
        first_iteration, elapsed = restore_irl_checkpoint(checkpoints.resume, reward_model=reward_model, optimizer=optimizer, history=history)
        first_iteration = checked_counter(first_iteration, "next iteration", 1, config.iterations + 1)
        started -= elapsed
    with StopAtBoundary(enabled=checkpoints is not None) as stop:
        for iteration in range(first_iteration, config.iterations + 1):
            rewards = all_state_rewards(reward_model, mdp.n_states).double()
            if not torch.isfinite(rewards).all():
                raise ImitationError(f"{config.method} IRL iteration {iteration}: the learned reward is not finite (diverged; try a lower --lr)")
            with np.errstate(over="ignore", invalid="ignore"):  # overflow shows as a non-finite loss, checked below
                policy, values = soft_value_iteration(
                    dynamics, rewards.detach().numpy(), horizon=horizon, discount=config.discount, method=config.method
                )
            occupancy = state_visitation(dynamics, mdp.initial, policy, horizon=horizon, discount=config.discount)
            # Its gradient is Σ_s (D_θ(s) - D̃(s)) ∇r_θ(s) = -∇L(θ): descending it ascends the likelihood.
            surrogate = (torch.as_tensor(occupancy) - target) @ rewards
            optimizer.zero_grad(set_to_none=True)
            surrogate.backward()
            gradient_norm = float(torch.cat([p.grad.reshape(-1) for p in reward_model.parameters()]).norm())
            error = float(np.abs(occupancy - demo_occupancy).max())
            # The negative log-likelihood (dual): log Z = E_ρ₀[V_0] minus the demos' score μ̃ᵀr.
            row = {
                "iteration": float(iteration),
                "loss": float(mdp.initial @ values - demo_occupancy @ rewards.detach().numpy()),
                "occupancy_error": error,
                "gradient_norm": gradient_norm,
            }
            if not (np.isfinite(row["loss"]) and np.isfinite(gradient_norm)):
                raise ImitationError(f"{config.method} IRL iteration {iteration}: the loss is {row['loss']} (diverged; try a lower --lr)")
            history.append(row)
            if log is not None:
                log(row)
            # The last iteration takes no step, so the reward returned is the one the policy,
            # occupancy and row above were computed for.
            if error <= config.tolerance or iteration == config.iterations:
                break
            optimizer.step()
            # A checkpoint every tenth of the iterations; Ctrl-C stops here (a finished run just finishes).
            interrupted = stop.requested and iteration < config.iterations
            if checkpoints is not None and (interrupted or (iteration % checkpoints.interval(config.iterations) == 0 and iteration < config.iterations)):
                checkpoints.save(*irl_checkpoint(iteration + 1, time.perf_counter() - started, reward_model=reward_model, optimizer=optimizer, history=history))
            if interrupted:
                raise TrainingInterrupted(f"{config.method} IRL stopped after iteration {iteration} of {config.iterations}")
    return MaxEntIRLResult(reward_model=reward_model, policy=policy, occupancy=occupancy, history=history, seconds=time.perf_counter() - started)


def irl_checkpoint(
    next_iteration: int, seconds: float, *, reward_model: RewardNet, optimizer: torch.optim.Optimizer, history: list[dict[str, float]]
) -> CheckpointData:
    """Everything `restore_irl_checkpoint` needs to continue at `next_iteration`: r_θ, Adam's state, the logged rows."""
    optimizer_tensors, optimizer_state = optimizer_checkpoint(optimizer, "optimizer")
    tensors = prefixed("reward", reward_model.state_dict()) | optimizer_tensors
    return snapshot(tensors, {"iteration": next_iteration, "seconds": seconds, "optimizer": optimizer_state, "history": history})


def restore_irl_checkpoint(
    checkpoint: CheckpointData, *, reward_model: RewardNet, optimizer: torch.optim.Optimizer, history: list[dict[str, float]]
) -> tuple[int, float]:
    """Load an `irl_checkpoint` (history is filled in place); returns (next iteration, seconds trained so far)."""
    tensors, state = checkpoint
    try:
        reward_model.load_state_dict(unprefixed("reward", tensors))
        restore_optimizer(optimizer, tensors, state["optimizer"], "optimizer")
        history += [floats(row) for row in state["history"]]
        return int(state["iteration"]), float(state["seconds"])
    except (KeyError, TypeError, ValueError, RuntimeError) as error:
        raise ImitationError(f"the checkpoint does not fit this tabular IRL run ({type(error).__name__}: {str(error).splitlines()[0]})") from None
