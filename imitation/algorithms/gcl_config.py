"""Guided cost learning's settings (`GCLConfig`), flags of `train irl --method gcl`
(imitation.flags). Light, like bc_config, for `train irl --help`."""

from __future__ import annotations

from dataclasses import dataclass

from imitation.errors import ConfigError
from imitation.flags import flag, hidden_sizes, seed

REWARD_INPUTS = ("s", "sa", "sas")  # imitation.rewards.REWARD_INPUTS, without its torch import
OBJECTIVES = ("discriminator", "importance")


@dataclass(kw_only=True)
class GCLConfig:
    hidden_sizes: list[int] = flag(
        name="--hidden",
        parse=hidden_sizes,
        metavar="32,32",
        help="reward MLP widths, or 'linear'",
        default_factory=lambda: [64, 64],
    )
    inputs: str = flag(
        "s",
        name="--reward-inputs",
        choices=REWARD_INPUTS,
        help="what the reward reads, the state s, its action a and next state s'",
    )
    learning_rate: float = flag(3e-4, name="--lr", metavar="LR", help="Adam learning rate of the reward")
    reward_steps: int = 8
    batch_size: int = 256
    gradient_penalty: float = 1.0
    warmup_steps: int = 200
    objective: str = "discriminator"
    # α of the reward PPO optimises alongside, r_θ(s) - α log π_k(a|s) (see gcl.py's docstring).
    policy_entropy: float = 1.0
    anneal_lr: bool = True
    seed: int = flag(0, parse=seed, metavar="S", help="seed")

    def validate(self) -> None:
        if self.objective not in OBJECTIVES:
            raise ConfigError(
                "objective", f"must be one of {', '.join(OBJECTIVES)}, got {self.objective!r}", owner="GCLConfig"
            )
        if not 0 < self.learning_rate < 1e30:  # NaN fails too; from ~1e37 Adam's step overflows float32
            raise ConfigError(
                "learning_rate", f"must be a positive number below 1e30, got {self.learning_rate}", owner="GCLConfig"
            )
        if not 0 <= self.policy_entropy < float("inf"):
            raise ConfigError(
                "policy_entropy", f"(α) must be a finite number ≥ 0, got {self.policy_entropy}", owner="GCLConfig"
            )
