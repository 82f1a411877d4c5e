"""Tabular MaxEnt and MCE IRL's settings (`MaxEntIRLConfig`), flags of `train irl --method
maxent|mce` (imitation.flags). Light, like bc_config, for `train irl --help`."""

from __future__ import annotations

from dataclasses import dataclass

from imitation.errors import ConfigError
from imitation.flags import flag, hidden_sizes, seed


@dataclass(kw_only=True)
class MaxEntIRLConfig:
    method: str = "mce"
    discount: float = flag(1.0, metavar="G", help="discount γ of the visitation counts")
    iterations: int = flag(2000, metavar="N", help="most gradient steps")
    learning_rate: float = flag(0.05, name="--lr", metavar="LR", help="Adam learning rate of the reward")
    tolerance: float = flag(1e-4, metavar="E", help="stop when the visitation error (L∞) is below E")
    hidden_sizes: list[int] = flag(
        name="--hidden",
        parse=hidden_sizes,
        metavar="32,32",
        help="reward MLP widths, or 'linear'",
        default_text="linear",
        default_factory=list,
    )
    seed: int = flag(0, parse=seed, metavar="S", help="seed")

    def validate(self) -> None:
        from imitation.envs.tabular_planning import BACKUPS

        if self.method not in BACKUPS:
            raise ConfigError(
                "method", f"must be one of {', '.join(BACKUPS)} for tabular IRL, got {self.method!r}", owner="MaxEntIRLConfig"
            )
        if self.iterations < 1:
            raise ConfigError("iterations", f"must be at least 1, got {self.iterations}", owner="MaxEntIRLConfig")
        if not 0 < self.learning_rate < 1e30:  # NaN fails too; from ~1e37 Adam's step overflows float32
            raise ConfigError(
                "learning_rate", f"must be a positive number below 1e30, got {self.learning_rate}", owner="MaxEntIRLConfig"
            )
