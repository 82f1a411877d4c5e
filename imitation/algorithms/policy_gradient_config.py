"""Policy gradient's settings (`PGConfig`), each `train pg` flag one of its fields
(imitation.flags). Light, like bc_config, for `train pg --help`."""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

from imitation.errors import ConfigError
from imitation.flags import flag, hidden_sizes, seed

ESTIMATORS = ("return", "reward-to-go", "baseline", "actor-critic")
WITH_CRITIC = ("baseline", "actor-critic")


@dataclass(kw_only=True)
class PGConfig:
    """Hyperparameters; per-estimator and per-environment defaults are in `imitation.jobs.pg`."""

    env_id: str = flag(name="--env", metavar="ID", help="gymnasium environment id")
    estimator: str = flag("baseline", choices=ESTIMATORS, help="the weight of ∇log π(a_t|s_t)")
    total_steps: int = flag(
        100_000,
        name="--steps",
        metavar="N",
        help="environment steps in total",
        default_text="296000 for CartPole-v1, 197000 with actor-critic; 499000 for Pendulum-v1, 500000 with "
        "actor-critic; else 100000",
    )
    n_envs: int = flag(4, metavar="K", help="environment copies", default_text="per env, else 4")
    batch_steps: int = flag(
        2000,
        metavar="N",
        help="environment steps per gradient step, at least: episodes are finished",
        default_text="per env, else 2000",
    )
    rollout_steps: int | None = flag(
        None,
        metavar="N",
        help="actor-critic: N steps of every env copy per gradient step, as in A2C; episodes run on and the cut is "
        "bootstrapped with V; --batch-steps without it means whole episodes",
        default_text="2 for Pendulum-v1, else none",
    )
    gamma: float = flag(0.99, metavar="G", help="discount γ in [0, 1]", default_text="per env, else 0.99")
    n_step: int | None = flag(
        None, metavar="N", help="actor-critic: n-step advantages, TD(0) at 1", default_text="none, GAE(λ)"
    )
    gae_lambda: float = flag(0.95, metavar="L", help="actor-critic: GAE's λ in [0, 1]")
    learning_rate: float = flag(
        1e-2, name="--lr", metavar="LR", help="the policy's Adam learning rate", default_text="per env, else 0.01"
    )
    value_learning_rate: float = 1e-2
    anneal_lr: bool = True  # both learning rates fall linearly to 0 over total_steps
    value_steps: int = 5  # critic regression steps per batch
    normalize_advantages: bool = True  # divide w_t by its batch std (not centred: centring is a baseline)
    normalize_observations: bool = False
    normalize_rewards: bool = False
    entropy_coef: float = 0.0
    max_grad_norm: float | None = None
    hidden_sizes: list[int] = flag(
        name="--hidden",
        parse=hidden_sizes,
        metavar="W,W",
        help="hidden layer widths of the policy and critic, or 'linear'",
        default_factory=lambda: [64, 64],
    )
    activation: str = "tanh"
    log_std_init: float = 0.0
    seed: int = flag(0, parse=seed, metavar="S", help="seed for torch, the envs and sampling")
    device: str = "cpu"
    threads: int = 1

    def validate(self) -> None:
        owner = "PGConfig"
        if self.estimator not in ESTIMATORS:
            raise ConfigError("estimator", f"must be one of {', '.join(ESTIMATORS)}, got {self.estimator!r}", owner=owner)
        for name in ("total_steps", "n_envs", "batch_steps", "value_steps"):
            if getattr(self, name) < 1:
                raise ConfigError(name, f"must be at least 1, got {getattr(self, name)}", owner=owner)
        if self.n_step is not None:
            if self.estimator != "actor-critic":
                raise ConfigError("n_step", f"is for the actor-critic estimator, not {self.estimator}", owner=owner)
            if self.n_step < 1:
                raise ConfigError("n_step", f"must be at least 1, got {self.n_step}", owner=owner)
        if self.rollout_steps is not None:
            if self.estimator != "actor-critic":
                raise ConfigError("rollout_steps", f"is for the actor-critic estimator, not {self.estimator}", owner=owner)
            if self.rollout_steps < 1:
                raise ConfigError("rollout_steps", f"must be at least 1, got {self.rollout_steps}", owner=owner)
        if self.total_steps < self.steps_per_batch:
            raise ConfigError(
                "total_steps", f"{self.total_steps} is less than one batch ({self.steps_per_batch} steps)", owner=owner
            )
        for name in ("gamma", "gae_lambda"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ConfigError(name, f"must lie in [0, 1], got {getattr(self, name)}", owner=owner)
        for name in ("learning_rate", "value_learning_rate"):
            if not 0 < getattr(self, name) < 1e30:  # NaN fails too
                raise ConfigError(name, f"must be a positive number below 1e30, got {getattr(self, name)}", owner=owner)

    @property
    def steps_per_batch(self) -> int:
        """The fewest env steps a batch holds (exactly this many with `rollout_steps`)."""
        return self.batch_steps if self.rollout_steps is None else self.n_envs * self.rollout_steps

    @staticmethod
    def from_json(data: dict[str, Any]) -> PGConfig:
        known = {f.name for f in fields(PGConfig)}
        return PGConfig(**{key: value for key, value in data.items() if key in known})
