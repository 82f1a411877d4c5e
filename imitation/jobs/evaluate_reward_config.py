"""`eval reward`'s settings (`RewardEvaluationConfig`), each flag one of its fields
(imitation.flags). Light, like the learners' configs, for `eval reward --help`."""

from __future__ import annotations

from dataclasses import dataclass

from imitation.errors import ConfigError
from imitation.flags import flag


@dataclass(kw_only=True)
class RewardEvaluationConfig:
    retrain_steps: int | None = flag(
        None,
        metavar="N",
        help="PPO steps per retraining; 0 skips it",
        default_text="600000 for Pendulum-v1, 300000 for fixed-horizon CartPole, else 200000",
    )
    seeds: int = flag(3, metavar="K", help="retraining seeds per reward")
    coverage_uniform: int = 2048
    mean_samples: int = 512
    seed: int = flag(0, metavar="S", help="first retraining seed; also seeds the controls and EPIC sampling")
    jobs: int = flag(2, metavar="J", help="retrainings run side by side in local processes, one CPU thread each")
    demos: list[str] | None = flag(
        None,
        nargs="+",
        metavar="F.mcap",
        help="expert demos for the reference return and EPIC's coverage",
        default_text="those the reward was learned from",
    )

    def validate(self) -> None:
        for name in ("seeds", "jobs"):
            if getattr(self, name) < 1:
                raise ConfigError(name, f"must be at least 1, got {getattr(self, name)}", owner="RewardEvaluationConfig")
        if self.retrain_steps is not None and self.retrain_steps < 0:
            raise ConfigError(
                "retrain_steps", f"must be non-negative, got {self.retrain_steps}", owner="RewardEvaluationConfig"
            )
