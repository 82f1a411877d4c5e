"""Tabular MDPs with known dynamics, and the gymnasium env that plays one.

A `TabularMDP` is the tuple the MaxEnt IRL notes (§5.3) work with: transition tensor
P[s, a, s'], initial distribution ρ₀(s), horizon H, per-state features x(s) and the true reward
r(s) = w*ᵀx(s). `TabularEnv` steps it: observations are state indices (Discrete(S)), the reward
of step t is r(s_t), and every episode is truncated after exactly H steps, so an episode holds
H + 1 observations — the states whose occupancy MaxEnt IRL matches.

Built-in worlds (registered as gymnasium ids in `imitation.envs`):

- `gridworld(slip=0)`: 8×8, start in the top-left corner, an absorbing goal in the bottom-right
  corner, two walls of lava between them; features are one-hot cell types
  (floor, lava, goal) with true weights (0, -2, +2). `slip` is the chance that a move goes
  in one of the two perpendicular directions instead (half each).
- `cliff_world()`: seals' CliffWorld, 4×7: start bottom-left, goal bottom-right, the bottom
  row between them a cliff; reward -1 per step, -10 on the cliff, +10 at the goal; one-hot
  state features.
- `random_mdp(seed)`: S states, A actions, each (s, a) leading to `branching` random successors
  with Dirichlet probabilities, Gaussian features and reward weights.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np

from imitation.errors import ImitationError

# Moves of the four grid actions as (row, column) offsets: up, right, down, left.
GRID_MOVES = np.array([(-1, 0), (0, 1), (1, 0), (0, -1)])
GRID_ACTION_NAMES = ("up", "right", "down", "left")


@dataclass(frozen=True, kw_only=True)
class TabularMDP:
    """P[s, a, s'], ρ₀, H (None: infinite, discounted), features x(s), true reward r(s)."""

    transition: np.ndarray
    initial: np.ndarray
    features: np.ndarray
    reward: np.ndarray
    horizon: int | None
    discount: float = 1.0
    grid_shape: tuple[int, int] | None = None
    feature_names: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        n_states, n_actions, n_next = self.transition.shape
        if n_next != n_states or self.initial.shape != (n_states,) or self.reward.shape != (n_states,):
            raise ImitationError(
                f"tabular MDP: shapes do not agree (P {self.transition.shape}, ρ₀ {self.initial.shape}, r {self.reward.shape})"
            )
        if self.features.ndim != 2 or self.features.shape[0] != n_states:
            raise ImitationError(f"tabular MDP: features must be (states, d), got {self.features.shape}")
        if not np.allclose(self.transition.sum(-1), 1.0) or not np.isclose(self.initial.sum(), 1.0):
            raise ImitationError("tabular MDP: P[s, a, ·] and ρ₀ must each sum to 1")

    @property
    def n_states(self) -> int:
        return self.transition.shape[0]

    @property
    def n_actions(self) -> int:
        return self.transition.shape[1]


class TabularEnv(gym.Env):
    """Plays a TabularMDP; `time_step` is the env's clock, which time-indexed (finite-horizon)
    policies such as the soft-optimal expert read."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 4}

    def __init__(self, mdp: TabularMDP, render_mode: str | None = None) -> None:
        if mdp.horizon is None:
            raise ImitationError("a tabular env needs a finite horizon (episodes end after exactly H steps)")
        self.mdp = mdp
        self.observation_space = gym.spaces.Discrete(mdp.n_states)
        self.action_space = gym.spaces.Discrete(mdp.n_actions)
        self.render_mode = render_mode
        self.state = 0
        self.time_step = 0

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[int, dict[str, Any]]:
        super().reset(seed=seed)
        self.state = int(self.np_random.choice(self.mdp.n_states, p=self.mdp.initial))
        self.time_step = 0
        return self.state, {}

    def step(self, action: Any) -> tuple[int, SupportsFloat, bool, bool, dict[str, Any]]:
        reward = float(self.mdp.reward[self.state])
        self.state = int(self.np_random.choice(self.mdp.n_states, p=self.mdp.transition[self.state, int(action)]))
        self.time_step += 1
        assert self.mdp.horizon is not None  # checked in __init__
        return self.state, reward, False, self.time_step >= self.mdp.horizon, {}

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array" or self.mdp.grid_shape is None:
            return None
        rows, columns = self.mdp.grid_shape
        cell = 24
        shade = (self.mdp.reward - self.mdp.reward.min()) / (np.ptp(self.mdp.reward) or 1.0)
        image = np.repeat(np.repeat((shade.reshape(rows, columns) * 200 + 40).astype(np.uint8), cell, 0), cell, 1)
        frame = np.stack([image] * 3, axis=-1)
        row, column = divmod(self.state, columns)
        frame[row * cell + 6 : (row + 1) * cell - 6, column * cell + 6 : (column + 1) * cell - 6] = (220, 40, 40)
        return frame


def _grid_transitions(cell_kind: np.ndarray, absorbing: np.ndarray, slip: float) -> np.ndarray:
    """P for the four moves on a grid: walking into the border stays put; with probability
    `slip` the move is turned 90° left or right (half each); absorbing cells never leave."""
    rows, columns = cell_kind.shape
    n_states = rows * columns
    transition = np.zeros((n_states, 4, n_states))
    for state in range(n_states):
        row, column = divmod(state, columns)
        for action in range(4):
            if absorbing[row, column]:
                transition[state, action, state] = 1.0
                continue
            outcomes = [(action, 1.0 - slip), ((action + 1) % 4, slip / 2), ((action + 3) % 4, slip / 2)]
            for move, probability in outcomes:
                next_row = min(max(row + GRID_MOVES[move][0], 0), rows - 1)
                next_column = min(max(column + GRID_MOVES[move][1], 0), columns - 1)
                transition[state, action, next_row * columns + next_column] += probability
    return transition


_GRIDWORLD_8X8 = [
    "S.......",
    "........",
    "..LLL...",
    "......L.",
    ".L....L.",
    ".L..LLL.",
    ".L......",
    ".......G",
]
_GRID_KINDS = ("floor", "lava", "goal")
_GRID_WEIGHTS = np.array([0.0, -2.0, 2.0])


def gridworld(*, slip: float = 0.0, horizon: int = 30) -> TabularMDP:
    """The 8×8 lava gridworld; `slip` > 0 makes the moves stochastic."""
    layout = np.array([list(row) for row in _GRIDWORLD_8X8])
    kind = np.select([layout == "L", layout == "G"], [1, 2], default=0)
    features = np.eye(len(_GRID_KINDS))[kind.reshape(-1)]
    initial = (layout == "S").reshape(-1).astype(np.float64)
    return TabularMDP(
        transition=_grid_transitions(kind, layout == "G", slip),
        initial=initial,
        features=features,
        reward=features @ _GRID_WEIGHTS,
        horizon=horizon,
        grid_shape=(layout.shape[0], layout.shape[1]),
        feature_names=_GRID_KINDS,
    )


def cliff_world(*, rows: int = 4, columns: int = 7, horizon: int = 40) -> TabularMDP:
    """seals' CliffWorld: start bottom-left, goal bottom-right (absorbing), the bottom row
    between them a cliff (absorbing); -1 per step, -10 on the cliff, +10 at the goal."""
    kind = np.zeros((rows, columns), dtype=int)
    kind[-1, 1:-1] = 1
    kind[-1, -1] = 2
    reward = np.select([kind == 1, kind == 2], [-10.0, 10.0], default=-1.0).reshape(-1)
    n_states = rows * columns
    initial = np.zeros(n_states)
    initial[(rows - 1) * columns] = 1.0
    return TabularMDP(
        transition=_grid_transitions(kind, kind > 0, 0.0),
        initial=initial,
        features=np.eye(n_states),
        reward=reward,
        horizon=horizon,
        grid_shape=(rows, columns),
    )


def random_mdp(
    *, seed: int = 0, n_states: int = 32, n_actions: int = 4, branching: int = 4, n_features: int = 8, horizon: int = 20
) -> TabularMDP:
    """A random MDP drawn from `seed`: sparse random dynamics, Gaussian features and weights."""
    rng = np.random.default_rng(seed)
    transition = np.zeros((n_states, n_actions, n_states))
    for state in range(n_states):
        for action in range(n_actions):
            successors = rng.choice(n_states, size=branching, replace=False)
            transition[state, action, successors] = rng.dirichlet(np.ones(branching))
    features = rng.normal(size=(n_states, n_features))
    return TabularMDP(
        transition=transition,
        initial=rng.dirichlet(np.ones(n_states)),
        features=features,
        reward=features @ rng.normal(size=n_features),
        horizon=horizon,
    )


def make_tabular_env(world: str, render_mode: str | None = None, **options: Any) -> TabularEnv:
    """The gymnasium entry point for the registered worlds."""
    builders: dict[str, Callable[..., TabularMDP]] = {
        "gridworld": gridworld,
        "cliff_world": cliff_world,
        "random_mdp": random_mdp,
    }
    return TabularEnv(builders[world](**options), render_mode=render_mode)


def tabular_mdp_of(env: gym.Env, *, where: str) -> TabularMDP:
    """The MDP behind a tabular env; a one-line error for any other env."""
    unwrapped = env.unwrapped
    if not isinstance(unwrapped, TabularEnv):
        name = env.spec.id if env.spec else type(unwrapped).__name__
        raise ImitationError(
            f"{where}: {name} is not a tabular MDP with known dynamics (use an imitation/ gridworld, or --method gcl)"
        )
    return unwrapped.mdp
