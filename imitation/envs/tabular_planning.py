"""Planning in a tabular MDP with known dynamics: soft value iteration (the backward pass) and
state visitation (the forward pass), which maximum-entropy IRL runs every iteration, the tabular
expert acts by, and reward evaluation scores policies with (docs/THEORY.md §7).

- backward pass (soft value iteration), V_H(s) = r(s), for t = H-1 … 0:
      mce    (maximum *causal* entropy, Ziebart 2010; exact for stochastic dynamics):
             Q_t(s, a) = r(s) + γ Σ_{s'} P(s'|s, a) V_{t+1}(s')
      maxent (Ziebart 2008; exact for deterministic dynamics, where both coincide):
             Q_t(s, a) = r(s) + γ log Σ_{s'} P(s'|s, a) exp V_{t+1}(s')
      V_t(s) = log Σ_a exp Q_t(s, a),   π_t(a|s) = exp(Q_t(s, a) - V_t(s))
- forward pass: D_0 = ρ₀, D_{t+1}(s') = Σ_{s, a} D_t(s) π_t(a|s) P(s'|s, a), and
  D(s) = Σ_{t=0}^{H} γ^t D_t(s), which sums to H + 1 when γ = 1.

With H = None the MDP is infinite-horizon and discounted (γ < 1 is then required): V and π are
stationary, found by iterating the backward step to a fixed point, and D sums to 1/(1-γ).

Large MDPs store their dynamics sparsely, as K successors per (s, a): gridworlds have K ≤ 3, so
both passes cost O(S·A·K) per step instead of the O(S²·A) of a dense P; small ones use dense
matrix products, which cost fewer numpy calls.
"""

from __future__ import annotations

import numpy as np

from imitation.envs.tabular import TabularMDP
from imitation.errors import ConfigError, ImitationError

BACKUPS = ("maxent", "mce")
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


def check_horizon(horizon: int | None, discount: float) -> None:
    """γ in (0, 1], below 1 when the horizon is infinite; H ≥ 1 when finite."""
    if not 0.0 < discount <= 1.0:
        raise ConfigError("discount", f"must be in (0, 1], got {discount}")
    if horizon is None and discount >= 1.0:
        raise ImitationError(
            "an infinite horizon needs a discount below 1 (the undiscounted occupancy is infinite); give a horizon or a "
            "discount < 1"
        )
    if horizon is not None and horizon < 1:
        raise ImitationError(f"horizon must be at least 1, got {horizon}")


def soft_value_iteration(
    dynamics: Dynamics, reward: np.ndarray, *, horizon: int | None, discount: float, method: str = "mce"
) -> tuple[np.ndarray, np.ndarray]:
    """The backward pass: (π, V_0) with π of shape (H, S, A), or (S, A) when H is None."""
    check_horizon(horizon, discount)
    if method not in BACKUPS:
        raise ImitationError(f"method must be one of {', '.join(BACKUPS)}, got {method!r}")
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
    check_horizon(horizon, discount)
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


def soft_optimal_policy(mdp: TabularMDP, reward: np.ndarray | None = None, *, discount: float | None = None) -> np.ndarray:
    """π_t(a|s) of shape (H, S, A), soft-optimal (causal, for any dynamics) for `reward` (default:
    the MDP's true one) and `discount` (default: the MDP's)."""
    dynamics = Dynamics.of(mdp.transition)
    reward = mdp.reward if reward is None else reward
    policy, _ = soft_value_iteration(
        dynamics, reward, horizon=mdp.horizon, discount=mdp.discount if discount is None else discount
    )
    return policy


def soft_optimal_returns(mdp: TabularMDP, reward: np.ndarray, *, discount: float) -> dict[str, float]:
    """True expected returns of the policies soft-optimal for `reward` and for the true reward,
    of the uniform policy, and the first normalised between the other two."""
    dynamics = Dynamics.of(mdp.transition)
    learned = expected_return(dynamics, mdp, soft_optimal_policy(mdp, reward, discount=discount))
    expert = expected_return(dynamics, mdp, soft_optimal_policy(mdp, discount=discount))
    random = expected_return(dynamics, mdp, np.full((mdp.horizon, mdp.n_states, mdp.n_actions), 1.0 / mdp.n_actions))
    return {
        "learned_policy_return": learned,
        "expert_return": expert,
        "random_return": random,
        "normalized_return": (learned - random) / (expert - random),
    }
