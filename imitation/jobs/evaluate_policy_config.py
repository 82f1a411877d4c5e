"""`eval policy`'s settings (`PolicyEvaluationConfig`), each flag one of its fields
(imitation.flags). Light, like the learners' configs, for `eval policy --help`."""

from __future__ import annotations

from dataclasses import dataclass

from imitation.errors import ConfigError
from imitation.flags import flag, seed


@dataclass(kw_only=True)
class PolicyEvaluationConfig:
    episodes: int = flag(10, metavar="N", help="episodes")
    seed: int = flag(0, parse=seed, metavar="S", help="episode i is reset with seed S+i")
    stochastic: bool = flag(False, help="sample actions instead of taking the most likely one")
    # The normalised return's 1: these demos' mean return (None: those the run learnt from).
    demos: list[str] | None = flag(
        None,
        nargs="+",
        metavar="F.mcap",
        help="demos whose mean return is the normalised score's 1",
        default_text="those the run learnt from",
    )
    video: str | None = flag(
        None, metavar="FILE.mp4|.gif", help="also write episode 0 (seed S) as a video", default_text="none"
    )

    def validate(self) -> None:
        if self.episodes < 1:
            raise ConfigError("episodes", f"must be at least 1, got {self.episodes}", owner="PolicyEvaluationConfig")
