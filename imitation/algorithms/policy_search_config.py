"""Gradient-free policy search's settings (`SearchConfig`), each flag of `train hill-climb`,
`train cem` and `train cmaes` one of its fields (imitation.flags); the command names the method.
Light, like bc_config, for their `--help`."""

from __future__ import annotations

import math
from dataclasses import dataclass

from imitation.errors import ConfigError
from imitation.flags import flag, hidden_sizes, seed

METHODS = ("hill-climb", "cem", "cmaes")
NAMES = {"hill-climb": "hill climbing", "cem": "CEM", "cmaes": "CMA-ES"}


@dataclass(kw_only=True)
class SearchConfig:
    """Settings of one search; per-environment presets are in `imitation.jobs.search.PRESETS`."""

    env_id: str = flag(name="--env", metavar="ID", help="gymnasium environment id")
    method: str = "cem"
    total_steps: int = flag(
        50_000,
        name="--steps",
        metavar="N",
        help="environment steps in total",
        default_text="50000 for CartPole-v1, 500000 for Pendulum-v1, else 100000",
    )
    population: int = flag(
        16, metavar="K", help="candidates per generation, besides the centre", default_text="24 for Pendulum-v1, else 16"
    )
    elite_fraction: float = flag(0.2, metavar="F", help="cem: the fraction of candidates the distribution is refitted to")
    sigma: float = flag(0.5, metavar="S", help="initial noise scale: hill climbing's σ, CEM's std, CMA-ES's step size")
    extra_noise: float = 0.05  # z₀, CEM's extra variance at generation 0
    extra_noise_generations: int = 25  # t_Z, the generation where CEM's extra variance reaches 0
    sigma_min: float = 1e-3  # hill climbing's clamp of σ
    sigma_max: float = 2.0
    success_factor: float = 0.5  # c_success: hill climbing's σ multiplier after an improvement
    failure_factor: float = 2.0  # c_failure: after a generation without one
    episodes_per_candidate: int = flag(1, metavar="E", help="episodes each candidate is scored on")
    n_envs: int = flag(8, metavar="K", help="environment copies")
    hidden_sizes: list[int] = flag(
        name="--hidden",
        parse=hidden_sizes,
        metavar="W,W",
        help="hidden layer widths of the policy, or 'linear'",
        default_text="8 for Pendulum-v1, else linear",
        default_factory=list,
    )
    activation: str = "tanh"
    seed: int = flag(0, parse=seed, metavar="S", help="seed of the search and its episodes")
    threads: int = 1

    def validate(self) -> None:
        owner = "SearchConfig"
        if self.method not in METHODS:
            raise ConfigError("method", f"must be one of {', '.join(METHODS)}, got {self.method!r}", owner=owner)
        for name in ("total_steps", "population", "episodes_per_candidate", "n_envs", "extra_noise_generations"):
            if getattr(self, name) < 1:
                raise ConfigError(name, f"must be at least 1, got {getattr(self, name)}", owner=owner)
        if self.method == "cmaes" and self.population < 2:
            raise ConfigError("population", f"must be at least 2 for CMA-ES, got {self.population}", owner=owner)
        if not 0 < self.elite_fraction <= 1:
            raise ConfigError("elite_fraction", f"must be in (0, 1], got {self.elite_fraction}", owner=owner)
        for name in ("sigma", "sigma_min", "sigma_max", "success_factor", "failure_factor"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(name, f"must be a positive finite number, got {value}", owner=owner)
        if not (math.isfinite(self.extra_noise) and self.extra_noise >= 0):
            raise ConfigError("extra_noise", f"must be a finite number ≥ 0, got {self.extra_noise}", owner=owner)
        if self.sigma_min > self.sigma_max:
            raise ConfigError(
                "sigma_min", f"{self.sigma_min} is above sigma_max {self.sigma_max}: the clamp is empty", owner=owner
            )
