"""config.json of a run directory, typed: one schema for every job, written in one place.

Each job fills the fields of its kind and leaves the rest None (left out of the file), so the
files read as before: {"kind": "bc", "env_id": …, "bc": {…BCConfig…}, "policy": {…}, …}.
Reading is lenient about fields it does not know, so run directories of other versions load.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields, is_dataclass
from pathlib import Path
from typing import Any

from imitation import __version__
from imitation.data.mcap.source import is_url

CREATOR = f"imitation-mcap {__version__}"


def config_json(config: Any) -> dict[str, Any]:
    """An algorithm's config dataclass as the JSON object its section of config.json holds."""
    assert is_dataclass(config) and not isinstance(config, type)
    return asdict(config)


@dataclass(kw_only=True)
class RunConfig:
    kind: str  # "bc", "dagger", "ppo", "search", "pg", "reward" (tabular IRL, GCL, a saved reward) or "reward-evaluation"
    env_id: str | None
    creator: str = CREATOR
    offline: bool | None = None  # bc: trained without an env
    demos_env_id: str | None = None  # bc: the env the demos say they are of
    expert: str | None = None  # dagger: the expert's spec
    demos: list[str] | None = None  # the demo files the run learnt from (or whose reward it optimised)
    demo_fingerprints: list[str] | None = None  # their content, for --resume to tell a change
    reward_run: str | None = None  # ppo: the reward run it optimised
    source: str | None = None  # where the reward the run holds or optimised came from, when no run says it
    bc: dict[str, Any] | None = None
    dagger: dict[str, Any] | None = None
    ppo: dict[str, Any] | None = None
    irl: dict[str, Any] | None = None
    search: dict[str, Any] | None = None  # hill-climb, cem, cmaes: the gradient-free search's config
    pg: dict[str, Any] | None = None  # pg: the policy-gradient config
    reward: dict[str, Any] | None = None  # RewardConfig of the reward model the run holds
    potential: dict[str, Any] | None = None  # AIRL: RewardConfig of the shaping potential h it also holds
    policy: dict[str, Any] | None = None  # PolicyConfig of the policy the run holds
    split: dict[str, Any] | None = None  # bc: which episodes or steps were held out
    world_size: int | None = None  # bc under torchrun: the data-parallel processes (None: one)
    run: str | None = None  # reward-evaluation: the run evaluated
    evaluation: dict[str, Any] | None = None  # reward-evaluation: its settings

    def to_json(self) -> dict[str, Any]:
        return {name: value for name, value in asdict(self).items() if value is not None}

    @staticmethod
    def from_json(data: dict[str, Any]) -> RunConfig:
        known = {f.name for f in fields(RunConfig)}
        given = {name: value for name, value in data.items() if name in known}
        return RunConfig(**given | {"kind": str(data.get("kind", "unknown")), "env_id": data.get("env_id")})

    def existing_demos(self) -> list[str]:
        """The demo files it names that are still there (URLs are kept unchecked)."""
        return [str(path) for path in self.demos or [] if is_url(path) or Path(path).is_file()]
