"""Apprenticeship learning's settings (`ApprenticeshipConfig`), flags of `train irl --method
apprenticeship` (imitation.flags). Light, like bc_config, for `train irl --help`."""

from __future__ import annotations

from dataclasses import dataclass

from imitation.errors import ConfigError
from imitation.flags import flag, seed


@dataclass(kw_only=True)
class ApprenticeshipConfig:
    iterations: int = flag(20, metavar="N", help="most projection iterations")
    # Relative: stop when ‖μ_E - μ̄‖₂ ≤ tolerance · ‖μ_E‖₂.
    tolerance: float = flag(0.01, metavar="E", help="stop when ‖μ_E - μ̄‖₂ ≤ E·‖μ_E‖₂")
    discount: float = flag(1.0, metavar="G", help="discount γ of the feature expectations")
    solver_steps: int = flag(100_000, name="--steps", metavar="N", help="on Box observations: PPO steps per iteration")
    episodes: int = flag(
        10, metavar="N", help="on Box observations: episodes that estimate each policy's feature expectations"
    )
    seed: int = flag(0, parse=seed, metavar="S", help="seed")

    def validate(self) -> None:
        if self.iterations < 1:
            raise ConfigError("iterations", f"must be at least 1, got {self.iterations}", owner="ApprenticeshipConfig")
        if not 0.0 <= self.tolerance < 1.0:
            raise ConfigError(
                "tolerance", f"must be in [0, 1) (a fraction of ‖μ_E‖), got {self.tolerance}", owner="ApprenticeshipConfig"
            )
        if self.episodes < 1:
            raise ConfigError("episodes", f"must be at least 1, got {self.episodes}", owner="ApprenticeshipConfig")


# ------------------------------------------------------------------------------------------------
# The formulas, as pure functions (tested against values worked by hand).
