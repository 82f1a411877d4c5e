"""Tabular maximum-entropy IRL (docs/THEORY.md §7): Ziebart et al. 2008 and its causal variant.

The model: a trajectory τ = (s_0, a_0, …, s_H) of an MDP with known dynamics P is scored by
its discounted reward R_θ(τ) = Σ_{t=0}^{H} γ^t r_θ(s_t) over all H + 1 states it visits, with
r_θ(s) = wᵀx(s) (linear in the features x) or an MLP on x(s). Learning maximises the demos'
likelihood, whose gradient is

    ∇L(θ) = Σ_s (D̃(s) - D_θ(s)) ∇r_θ(s),     for linear r:  μ̃ - Σ_s D_θ(s) x(s)

with D̃ the demos' (discounted) state visitation frequencies (`demo_visitation`) and D_θ those
of the policy that is soft-optimal for r_θ, computed each iteration by soft value iteration and
the forward visitation pass (`imitation.envs.tabular_planning`: `maxent` backs up with the log
of the expected exponentiated value, Ziebart 2008, exact for deterministic dynamics; `mce`, the
maximum *causal* entropy backup of Ziebart 2010, with the expected value, exact for any).

Each step of `MaxEntIRL` is one Adam step on r_θ's parameters along that gradient; nothing in
an iteration is random, so a run resumed from its state ends exactly where it would have.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import torch

from imitation.algorithms.maxent_irl_config import MaxEntIRLConfig
from imitation.checkpoints import CheckpointData, CheckpointReader, CheckpointWriter, TrainingClock
from imitation.data.types import Episode, Transitions
from imitation.envs.tabular import TabularMDP
from imitation.envs.tabular_planning import Dynamics, check_horizon, soft_value_iteration, state_visitation
from imitation.errors import ConfigError, ImitationError
from imitation.rewards import RewardNet, all_state_rewards


def demo_visitation(
    demos: Iterable[Episode] | Transitions, *, n_states: int, horizon: int | None, discount: float
) -> np.ndarray:
    """D̃(s) = (1/m) Σ_j Σ_{t=0}^{T_j} γ^t 1[s_t^j = s] over m demo episodes (each of H steps when
    the horizon is finite, so its H + 1 observations are all counted).

    Transitions carry no time index, so they are accepted for γ = 1 only: every observation, and
    the final next-observation of each episode, counts once, divided by the number of episodes."""
    check_horizon(horizon, discount)
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
        raise ImitationError(
            f"{where}: observation {int(states.max() if states.max() >= n_states else states.min())} is not a state of an "
            f"MDP with {n_states} states"
        )


class MaxEntIRL:
    """The learner: r_θ, Adam, and one iteration per step (backward pass, forward pass, the
    likelihood's gradient, one Adam step), until the learned visitation D_θ matches D̃ to
    `tolerance` (L∞) or the iterations run out. The reward, the soft-optimal `policy` for it and
    its `occupancy` are those of the last iteration (which takes no Adam step)."""

    unit = "iteration"

    def __init__(self, mdp: TabularMDP, demo_occupancy: np.ndarray, reward_model: RewardNet, config: MaxEntIRLConfig) -> None:
        config.validate()
        check_horizon(mdp.horizon, config.discount)
        if demo_occupancy.shape != (mdp.n_states,):
            raise ImitationError(f"demo occupancy has shape {demo_occupancy.shape}, the MDP has {mdp.n_states} states")
        torch.manual_seed(config.seed)
        self.dynamics = Dynamics.of(mdp.transition)
        if config.method == "maxent" and not self.dynamics.is_deterministic:
            raise ConfigError(
                "method",
                "maxent (Ziebart 2008) assumes deterministic dynamics and this MDP's are stochastic; use mce",
                owner="MaxEntIRLConfig",
            )
        self.name = f"{config.method} IRL"
        self.mdp, self.demo_occupancy, self.reward_model, self.config = mdp, demo_occupancy, reward_model, config
        self.total = config.iterations
        # fused: one kernel for the whole step, fewer calls on the small tabular reward
        self.optimizer = torch.optim.Adam(reward_model.parameters(), lr=config.learning_rate, fused=True)
        self.target = torch.as_tensor(demo_occupancy)
        self.iterations = 0
        self.clock = TrainingClock()
        self.converged = False
        self.policy: np.ndarray | None = None
        self.occupancy: np.ndarray | None = None

    @property
    def completed(self) -> int:
        return self.iterations

    @property
    def done(self) -> bool:
        return self.converged or self.iterations >= self.total

    def position(self) -> str:
        return f"iteration {self.iterations} of {self.total}"

    def progress(self, row: dict[str, float]) -> dict[str, str]:
        return {"error": f"{row['occupancy_error']:.2e}", "loss": f"{row['loss']:.3f}"}

    def step(self) -> dict[str, float]:
        config, mdp = self.config, self.mdp
        self.clock.start()
        iteration = self.iterations + 1
        rewards = all_state_rewards(self.reward_model, mdp.n_states).double()
        if not torch.isfinite(rewards).all():
            raise ImitationError(
                f"{config.method} IRL iteration {iteration}: the learned reward is not finite (diverged; try a lower "
                "learning rate)"
            )
        with np.errstate(over="ignore", invalid="ignore"):  # overflow shows as a non-finite loss, checked below
            self.policy, values = soft_value_iteration(
                self.dynamics, rewards.detach().numpy(), horizon=mdp.horizon, discount=config.discount, method=config.method
            )
        self.occupancy = state_visitation(
            self.dynamics, mdp.initial, self.policy, horizon=mdp.horizon, discount=config.discount
        )
        # Its gradient is Σ_s (D_θ(s) - D̃(s)) ∇r_θ(s) = -∇L(θ): descending it ascends the likelihood.
        surrogate = (torch.as_tensor(self.occupancy) - self.target) @ rewards
        self.optimizer.zero_grad(set_to_none=True)
        surrogate.backward()
        gradients = []
        for parameter in self.reward_model.parameters():
            assert parameter.grad is not None  # every parameter of r_θ feeds the surrogate
            gradients.append(parameter.grad.reshape(-1))
        gradient_norm = float(torch.cat(gradients).norm())
        error = float(np.abs(self.occupancy - self.demo_occupancy).max())
        # The negative log-likelihood (dual): log Z = E_ρ₀[V_0] minus the demos' score μ̃ᵀr.
        with np.errstate(over="ignore", invalid="ignore"):  # overflow shows as a non-finite loss, checked below
            loss = float(mdp.initial @ values - self.demo_occupancy @ rewards.detach().numpy())
        row = {"iteration": float(iteration), "loss": loss, "occupancy_error": error, "gradient_norm": gradient_norm}
        if not (np.isfinite(loss) and np.isfinite(gradient_norm)):
            raise ImitationError(
                f"{config.method} IRL iteration {iteration}: the loss is {loss} and the gradient norm {gradient_norm} "
                "(diverged; try a lower learning rate)"
            )
        self.iterations = iteration
        self.converged = error <= config.tolerance
        # The last iteration takes no step, so the reward returned is the one the policy,
        # occupancy and row above were computed for.
        if not self.done:
            self.optimizer.step()
        return row

    def state_dict(self) -> CheckpointData:
        """r_θ and Adam's state: an iteration holds nothing else that carries over."""
        checkpoint = CheckpointWriter(iteration=self.iterations + 1)
        checkpoint.clock(self.clock)
        checkpoint.module("reward", self.reward_model.state_dict())
        checkpoint.optimizer(self.optimizer)
        return checkpoint.data()

    def load_state_dict(self, checkpoint: CheckpointData) -> None:
        with CheckpointReader(checkpoint, "tabular IRL") as saved:
            self.reward_model.load_state_dict(saved.module("reward"))
            saved.optimizer(self.optimizer)
            saved.clock(self.clock)
            self.iterations = saved.counter("iteration", "next iteration", 1, self.total + 1) - 1
