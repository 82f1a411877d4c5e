"""EPIC: the Equivalent-Policy Invariant Comparison of two rewards (Gleave et al. 2020,
"Quantifying Differences in Reward Functions", arXiv 2006.13900; docs/THEORY.md §9).

Two rewards that differ by potential shaping F(s, a, s') = γΦ(s') − Φ(s), or by a positive
scale, have the same optimal policies in every MDP with the same (S, A, γ); EPIC is a distance
that is zero between such rewards. It has two steps.

1. Canonicalise each reward, which removes potential shaping (Definition 4.1 of the paper):

       C(R)(s, a, s') = R(s, a, s') + E[γR(s', A, S') − R(s, A, S') − γR(S, A, S')]

   with S, S' ~ D_S and A ~ D_A independent. Writing m(x) = E[R(x, A, S')] for the mean reward
   out of state x and c = E[m(S)], this is C(R)(s, a, s') = R(s, a, s') + γm(s') − m(s) − γc:
   shaping R by Φ moves m(x) by γE[Φ(S')] − Φ(x), which cancels the shaping term exactly, for
   any D_S and D_A. D_S and D_A should be broad (uniform over the state and action spaces):
   the canonical reward only depends on R where they put mass.

2. Compare the canonical rewards by the Pearson distance over a coverage distribution D of
   transitions (s, a, s'), which also removes the scale:

       D_EPIC(R_A, R_B) = D_ρ(C(R_A)(S, A, S'), C(R_B)(S, A, S')),   (S, A, S') ~ D,
       D_ρ(X, Y) = √((1 − ρ(X, Y)) / 2)

   It lies in [0, 1]: 0 for equivalent rewards, √½ for uncorrelated ones, 1 for R vs −R.
   D is where the two rewards must agree: on a tabular MDP, all transitions (uniform) or those
   a policy visits; on a continuous env, a mix of demo transitions, policy rollouts and uniform
   samples of the space's bounds (`coverage_samples`).

`epic_distance_tabular` computes both steps exactly by expectations; `epic_distance_sampled`
estimates m(x) and c by Monte-Carlo means over N_M samples of (A, S') (the paper's sample-based
estimator), which keeps the exact shaping invariance since the same samples serve every state.
Both also report the plain Pearson correlation of the un-canonicalised rewards, which shaping
and constant offsets between states can hide a good reward behind.

A reward that is constant after canonicalisation (a constant, or pure shaping) states no
preference at all, so its correlation with anything is undefined: it is taken as uncorrelated
(ρ = 0, EPIC = √½) with a reward that does state one, and as equivalent (ρ = 1, EPIC = 0) to
another such reward.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple, Protocol

import gymnasium as gym
import numpy as np
import torch

from imitation.errors import ImitationError

RewardFn = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]
"""R(s, a, s') on a batch: arrays of N states, N actions and N next states in, N rewards out."""

# Rows (state × mean sample) per reward call in the sampled estimator: large enough that per-call
# overhead is small, small enough that a small MLP's activations stay in cache (bench/RESULTS.md).
# Chunking also means 4096 transitions × 512 samples never hold the whole 4M-row product in memory.
_CHUNK_ROWS = 1 << 13
# A spread below this fraction of the reward's magnitude is float32 round-off (learned rewards
# are float32 networks), not a preference between transitions.
_CONSTANT_TOLERANCE = 1e-6


@dataclass(frozen=True)
class EpicResult:
    """`epic`: D_EPIC in [0, 1]; `pearson`: ρ of the raw rewards over the same coverage."""

    epic: float
    pearson: float


class TransitionBatch(NamedTuple):
    """N transitions (s, a, s') as three arrays with N rows each."""

    observations: np.ndarray
    actions: np.ndarray
    next_observations: np.ndarray


class HasTransitions(Protocol):
    """Anything with transition arrays: a TransitionBatch or imitation.data.types.Transitions."""

    @property
    def observations(self) -> np.ndarray: ...
    @property
    def actions(self) -> np.ndarray: ...
    @property
    def next_observations(self) -> np.ndarray | None: ...


# ------------------------------------------------------------------------------------------------
# The Pearson distance


def pearson_distance(correlation: float) -> float:
    """D_ρ = √((1 − ρ) / 2); ρ is clipped to [−1, 1] against round-off."""
    return float(np.sqrt((1.0 - np.clip(correlation, -1.0, 1.0)) / 2.0))


def _is_constant(values: np.ndarray, weights: np.ndarray, scale: float) -> bool:
    mean = weights @ values
    return float(np.sqrt(weights @ (values - mean) ** 2)) <= _CONSTANT_TOLERANCE * scale


def _correlation(x: np.ndarray, y: np.ndarray, weights: np.ndarray, x_scale: float, y_scale: float) -> float:
    """ρ(x, y) under `weights` (summing to 1); a side within round-off of constant (relative to
    `scale`, its reward's magnitude) counts as no preference, as the module docstring says."""
    x_constant, y_constant = _is_constant(x, weights, x_scale), _is_constant(y, weights, y_scale)
    if x_constant or y_constant:
        return 1.0 if x_constant and y_constant else 0.0
    x = x - weights @ x
    y = y - weights @ y
    return float((weights @ (x * y)) / np.sqrt((weights @ x**2) * (weights @ y**2)))


def _magnitude(values: np.ndarray, weights: np.ndarray) -> float:
    return float(np.sqrt(weights @ values**2))


def _distances(
    raw_a: np.ndarray, raw_b: np.ndarray, canonical_a: np.ndarray, canonical_b: np.ndarray, weights: np.ndarray
) -> EpicResult:
    """EPIC of the canonical rewards and Pearson of the raw ones, all flat over the coverage."""
    scale_a, scale_b = _magnitude(raw_a, weights), _magnitude(raw_b, weights)
    return EpicResult(
        epic=pearson_distance(_correlation(canonical_a, canonical_b, weights, scale_a, scale_b)),
        pearson=_correlation(raw_a, raw_b, weights, scale_a, scale_b),
    )


# ------------------------------------------------------------------------------------------------
# Tabular: exact expectations


def _distribution(weights: np.ndarray | None, shape: tuple[int, ...], name: str) -> np.ndarray:
    """Non-negative weights of `shape` normalised to sum to 1; uniform when None. Normalised here
    so that e.g. a visitation summing to H + 1 can be passed as it is."""
    if weights is None:
        return np.full(shape, 1.0 / np.prod(shape))
    weights = np.asarray(weights, dtype=np.float64)
    if weights.shape != shape:
        raise ImitationError(f"EPIC: {name} must have shape {shape}, got {weights.shape}")
    if np.any(weights < 0) or not weights.sum() > 0:
        raise ImitationError(f"EPIC: {name} must be non-negative with a positive sum")
    return weights / weights.sum()


def _transition_table(reward: np.ndarray, n_states: int, n_actions: int) -> np.ndarray:
    """A reward of shape (S,), (S, A) or (S, A, S') as R[s, a, s'], shape (S, A, S')."""
    reward = np.asarray(reward, dtype=np.float64)
    shapes = {1: (n_states,), 2: (n_states, n_actions), 3: (n_states, n_actions, n_states)}
    if shapes.get(reward.ndim) != reward.shape:
        raise ImitationError(
            f"EPIC: a tabular reward must have shape (S,), (S, A) or (S, A, S') with S = {n_states}, A = {n_actions}; got "
            f"{reward.shape}"
        )
    # Trailing axes of length 1 broadcast r(s) or r(s, a) over the missing a and s'.
    return np.broadcast_to(reward.reshape(reward.shape + (1,) * (3 - reward.ndim)), (n_states, n_actions, n_states))


def canonicalize_tabular(
    reward: np.ndarray, discount: float, state_dist: np.ndarray | None = None, action_dist: np.ndarray | None = None
) -> np.ndarray:
    """C(R)(s, a, s') = R(s, a, s') + γm(s') − m(s) − γc exactly, for R of shape (S, A, S'), with
    m(x) = Σ_{a, s'} D_A(a) D_S(s') R(x, a, s') and c = Σ_x D_S(x) m(x); D_S, D_A uniform by
    default."""
    _check_discount(discount)
    n_states, n_actions, _ = reward.shape
    states = _distribution(state_dist, (n_states,), "state_dist")
    actions = _distribution(action_dist, (n_actions,), "action_dist")
    mean_from = np.einsum("xat,a,t->x", reward, actions, states)
    constant = states @ mean_from
    return reward + discount * mean_from[None, None, :] - mean_from[:, None, None] - discount * constant


def epic_distance_tabular(
    reward_a: np.ndarray,
    reward_b: np.ndarray,
    n_states: int,
    n_actions: int,
    discount: float,
    state_dist: np.ndarray | None = None,
    action_dist: np.ndarray | None = None,
    transition_dist: np.ndarray | None = None,
) -> EpicResult:
    """Exact EPIC between two tabular rewards, each of shape (S,), (S, A) or (S, A, S').

    `state_dist` (S,) and `action_dist` (A,) are D_S and D_A of the canonicalisation (uniform
    by default). `transition_dist` (S, A, S') is the coverage distribution D: the joint weight of
    each transition (s, a, s'), not P(s'|s, a). By default it is uniform over all S·A·S'
    transitions; to compare the rewards where a policy goes, pass its visitation times its
    transitions, e.g. `np.einsum("s,sa,sat->sat", visitation, policy, mdp.transition)`. Any
    non-negative weights are normalised here.
    """
    table_a = _transition_table(reward_a, n_states, n_actions)
    table_b = _transition_table(reward_b, n_states, n_actions)
    coverage = _distribution(transition_dist, (n_states, n_actions, n_states), "transition_dist").reshape(-1)
    canonical_a = canonicalize_tabular(table_a, discount, state_dist, action_dist)
    canonical_b = canonicalize_tabular(table_b, discount, state_dist, action_dist)
    return _distances(table_a.reshape(-1), table_b.reshape(-1), canonical_a.reshape(-1), canonical_b.reshape(-1), coverage)


def tabulate(reward: RewardFn, n_states: int, n_actions: int) -> np.ndarray:
    """R[s, a, s'] of a reward function on state and action indices, for every transition: how a
    reward network on (s, a) or (s, a, s') of a tabular env enters `epic_distance_tabular`."""
    s, a, t = (index.reshape(-1) for index in np.indices((n_states, n_actions, n_states)))
    return _evaluate(reward, s, a, t).reshape(n_states, n_actions, n_states)


# ------------------------------------------------------------------------------------------------
# Sampled: Monte-Carlo means, for continuous spaces


def torch_reward(model: Callable[[torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor]) -> RewardFn:
    """A torch reward (e.g. a RewardNet, which encodes and normalises its inputs itself) as a
    RewardFn on numpy arrays, evaluated without gradients."""

    def reward(observations: np.ndarray, actions: np.ndarray, next_observations: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return (
                model(torch.as_tensor(observations), torch.as_tensor(actions), torch.as_tensor(next_observations))
                .double()
                .numpy()
            )

    return reward


def _evaluate(reward: RewardFn, observations: np.ndarray, actions: np.ndarray, next_observations: np.ndarray) -> np.ndarray:
    """R on a batch as float64 (means over many float32 values lose digits otherwise)."""
    values = np.asarray(reward(observations, actions, next_observations), dtype=np.float64)
    if values.shape != (len(observations),):
        raise ImitationError(
            f"EPIC: a reward on {len(observations)} transitions returned shape {values.shape}, expected ({len(observations)},)"
        )
    return values


def _mean_rewards(reward: RewardFn, states: np.ndarray, actions: np.ndarray, next_states: np.ndarray) -> np.ndarray:
    """m̂(x) = (1/N) Σ_j R(x, a_j, s'_j) for each state x, over the N paired samples (a_j, s'_j);
    evaluated on the product states × samples a chunk of states at a time."""
    n_samples = len(actions)
    per_chunk = max(1, _CHUNK_ROWS // n_samples)
    tiled_actions = np.tile(actions, (min(per_chunk, len(states)),) + (1,) * (actions.ndim - 1))
    tiled_next = np.tile(next_states, (min(per_chunk, len(states)),) + (1,) * (next_states.ndim - 1))
    means = np.empty(len(states))
    for start in range(0, len(states), per_chunk):
        chunk = states[start : start + per_chunk]
        rows = len(chunk) * n_samples
        values = _evaluate(reward, np.repeat(chunk, n_samples, axis=0), tiled_actions[:rows], tiled_next[:rows])
        means[start : start + len(chunk)] = values.reshape(len(chunk), n_samples).mean(axis=1)
    return means


def _unique_rows(states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The distinct states and, for each input row, its index among them. Along a trajectory
    each s' is the next s, so this halves the reward evaluations for rollout coverage."""
    _, first, inverse = np.unique(states.reshape(len(states), -1), axis=0, return_index=True, return_inverse=True)
    return states[first], inverse.reshape(-1)


def _canonical_and_raw(
    reward: RewardFn, transitions: TransitionBatch, state_samples: np.ndarray, action_samples: np.ndarray, discount: float
) -> tuple[np.ndarray, np.ndarray]:
    observations, actions, next_observations = transitions
    raw = _evaluate(reward, observations, actions, next_observations)
    unique, inverse = _unique_rows(np.concatenate([observations, next_observations, state_samples]))
    means = _mean_rewards(reward, unique, action_samples, state_samples)[inverse]
    mean_from, mean_from_next, mean_from_samples = np.split(means, [len(raw), 2 * len(raw)])
    # c = E[m(S)] over the same state samples that stand for S' in m̂: shaping then cancels exactly.
    return raw + discount * mean_from_next - mean_from - discount * mean_from_samples.mean(), raw


def canonicalize_sampled(
    reward: RewardFn, transitions: TransitionBatch, state_samples: np.ndarray, action_samples: np.ndarray, discount: float
) -> np.ndarray:
    """Ĉ(R)(s, a, s') = R(s, a, s') + γm̂(s') − m̂(s) − γĉ for each transition of the batch, with
    m̂(x) = (1/N) Σ_j R(x, a_j, s'_j) over the N paired samples (a_j = action_samples[j],
    s'_j = state_samples[j]) and ĉ = (1/N) Σ_i m̂(s'_i). The pairs must be independent draws of
    D_A and D_S (`epic_distance_sampled` draws them so)."""
    _check_discount(discount)
    _check_batch(transitions)
    if len(state_samples) != len(action_samples) or len(state_samples) == 0:
        raise ImitationError(
            f"EPIC: state and action samples must pair up, got {len(state_samples)} and {len(action_samples)}"
        )
    return _canonical_and_raw(reward, transitions, state_samples, action_samples, discount)[0]


def epic_distance_sampled(
    reward_a: RewardFn,
    reward_b: RewardFn,
    transitions: TransitionBatch,
    state_samples: np.ndarray,
    action_samples: np.ndarray,
    discount: float,
    seed: int = 0,
    n_mean_samples: int = 512,
) -> EpicResult:
    """EPIC estimated on a batch of transitions (s, a, s') drawn from the coverage distribution D
    (e.g. `coverage_samples`: demos, policy rollouts and uniform samples of the space's bounds).

    `state_samples` and `action_samples` are pools standing for D_S and D_A: they should cover
    the spaces broadly, e.g. `uniform_space_samples` of the bounds, or the coverage batch's own
    states and actions. From each pool `n_mean_samples` are drawn with `seed`, independently of
    each other, so that pools taken from the same transitions (where a_t depends on s_t) still
    give independent pairs (A, S'). Both rewards are canonicalised with the same pairs
    (`canonicalize_sampled`); the Pearson distance is the unweighted one over the batch.
    Rewards are plain RewardFns on numpy arrays; wrap torch ones with `torch_reward`.

    The estimate is exactly invariant to potential shaping and scale (its only error is the
    Monte-Carlo error of m̂, O(1/√N_M)); it costs 2·(2N + N_M)·N_M reward evaluations for N
    transitions, fewer when states repeat.
    """
    if n_mean_samples < 1:
        raise ImitationError(f"EPIC: n_mean_samples must be at least 1, got {n_mean_samples}")
    for name, pool in (("state_samples", state_samples), ("action_samples", action_samples)):
        if len(pool) == 0:
            raise ImitationError(f"EPIC: {name} is empty")
    _check_discount(discount)
    _check_batch(transitions)
    rng = np.random.default_rng(seed)
    states = state_samples[rng.choice(len(state_samples), n_mean_samples, replace=len(state_samples) < n_mean_samples)]
    actions = action_samples[rng.choice(len(action_samples), n_mean_samples, replace=len(action_samples) < n_mean_samples)]
    canonical_a, raw_a = _canonical_and_raw(reward_a, transitions, states, actions, discount)
    canonical_b, raw_b = _canonical_and_raw(reward_b, transitions, states, actions, discount)
    weights = np.full(len(raw_a), 1.0 / len(raw_a))
    return _distances(raw_a, raw_b, canonical_a, canonical_b, weights)


def _check_discount(discount: float) -> None:
    if not 0.0 <= discount <= 1.0:
        raise ImitationError(f"EPIC: discount must be in [0, 1], got {discount}")


def _check_batch(transitions: TransitionBatch) -> None:
    lengths = {len(part) for part in transitions}
    if len(transitions) != 3 or len(lengths) != 1 or 0 in lengths:
        raise ImitationError(
            "EPIC: transitions must be (s, a, s') arrays of one non-zero length, got lengths "
            f"{sorted(len(part) for part in transitions)}"
        )


# ------------------------------------------------------------------------------------------------
# Coverage for continuous envs


def uniform_space_samples(space: gym.Space, n: int, *, rng: np.random.Generator, reference: np.ndarray) -> np.ndarray:
    """n samples uniform over a Box's bounds (or a Discrete's values). Where a Box dimension is
    unbounded, its range is that of `reference` (e.g. the demo states) in that dimension: a
    reward is only worth comparing where states can be reached."""
    if isinstance(space, gym.spaces.Discrete):
        return rng.integers(int(space.start), int(space.start) + int(space.n), size=n).astype(space.dtype)
    if not isinstance(space, gym.spaces.Box):
        raise ImitationError(f"EPIC: coverage samples need Box or Discrete spaces, got {type(space).__name__}")
    reference = np.asarray(reference, dtype=np.float64).reshape((-1,) + space.shape)
    low, high = space.low.astype(np.float64), space.high.astype(np.float64)
    unbounded = ~(np.isfinite(low) & np.isfinite(high))
    if unbounded.any() and len(reference) == 0:
        raise ImitationError("EPIC: an unbounded Box dimension needs reference samples for its range")
    if unbounded.any():
        low = np.where(unbounded, reference.min(axis=0), low)
        high = np.where(unbounded, reference.max(axis=0), high)
    return rng.uniform(low, high, size=(n,) + space.shape).astype(space.dtype)


def _batch_of(source: HasTransitions, name: str) -> TransitionBatch:
    if source.next_observations is None:
        raise ImitationError(f"EPIC coverage: the {name} need next observations")
    return TransitionBatch(np.asarray(source.observations), np.asarray(source.actions), np.asarray(source.next_observations))


def coverage_samples(
    env: gym.Env, demos: HasTransitions, rollouts: HasTransitions | None = None, *, n_uniform: int, seed: int = 0
) -> TransitionBatch:
    """The coverage batch for `epic_distance_sampled` on a continuous env: the demo transitions
    (where the expert goes), the policy-rollout transitions if given (where the policy trained on
    a recovered reward goes; a reward may be wrong exactly there), and `n_uniform` transitions with
    s, a and s' independently uniform over the spaces (`uniform_space_samples`; unbounded
    dimensions span the demos' range), so the rewards must also agree off those paths. The three
    parts are concatenated as they are: their sizes are their weights in D.

    Uniform transitions are not dynamically feasible; the paper's "random transitions" coverage
    is the same product distribution D_S × D_A × D_S.
    """
    if n_uniform < 0:
        raise ImitationError(f"EPIC coverage: n_uniform must be non-negative, got {n_uniform}")
    parts = [_batch_of(demos, "demos")] + ([_batch_of(rollouts, "rollouts")] if rollouts is not None else [])
    rng = np.random.default_rng(seed)
    demo_states = np.concatenate([parts[0].observations, parts[0].next_observations])
    parts.append(
        TransitionBatch(
            uniform_space_samples(env.observation_space, n_uniform, rng=rng, reference=demo_states),
            uniform_space_samples(env.action_space, n_uniform, rng=rng, reference=parts[0].actions),
            uniform_space_samples(env.observation_space, n_uniform, rng=rng, reference=demo_states),
        )
    )
    return TransitionBatch(*(np.concatenate([part[field] for part in parts]) for field in range(3)))
