"""DAgger's settings (`DAggerConfig`), each field a `train dagger` flag (imitation.flags), with
the BC settings each round trains with. Light, like bc_config, for `train dagger --help`."""

from __future__ import annotations

from dataclasses import dataclass

from imitation.algorithms.bc_config import BCConfig
from imitation.errors import ConfigError
from imitation.flags import flag, nested, seed

SCHEDULES = ("linear", "exponential")
MODES = ("label", "takeover")
LABELS = ("human", "all")
# The BC settings `train dagger` takes as flags.
BC_FLAGS = (
    "policy",
    "history",
    "chunk",
    "execute",
    "ensemble",
    "angles",
    "denoising_steps",
    "sampling_steps",
    "sampling_noise",
    "observation_noise",
    "members",
    "prediction",
    "epochs",
    "patience",
    "hidden_sizes",
    "frame_stack",
    "random_shift",
    "mixed_precision",
    "seed",
    "device",
)


@dataclass(kw_only=True)
class DAggerConfig:
    rounds: int = flag(5, metavar="R", help="rounds")
    episodes_per_round: int = flag(5, metavar="N", help="rollouts per round")
    beta_schedule: str = flag("linear", choices=SCHEDULES, help="how β decays")
    beta_decay: float = flag(0.5, metavar="P", help="β_i = P^(i-1) for the exponential schedule")
    seed: int = flag(0, parse=seed, metavar="S", help="seed")
    # "label": the learner drives with probability 1 - β and the expert labels every state;
    # "takeover": the learner drives until the expert takes over (HG-DAgger).
    mode: str = flag(
        "label",
        choices=MODES,
        help="label: the expert labels every visited state (classic DAgger); takeover: the learner drives until the "
        "expert takes the controls (standin, keyboard, gamepad, pointer)",
    )
    # Take-over: "human" trains on the steps the expert drove; "all" also on the learner's own
    # actions where the expert let it drive.
    label: str = flag(
        "human",
        choices=LABELS,
        help="with --mode takeover: train on the steps the expert drove (human), or on all steps, taking the learner's "
        "actions the expert let pass as labels (all)",
    )
    # Each round warm-starts from the previous learner, so it needs fewer epochs than BC from scratch.
    bc: BCConfig = nested(BC_FLAGS, lambda: BCConfig(epochs=60, patience=15))

    def validate(self) -> None:
        for name, choices in (("mode", MODES), ("label", LABELS)):
            if getattr(self, name) not in choices:
                raise ConfigError(
                    name, f"must be one of {', '.join(choices)}, got {getattr(self, name)!r}", owner="DAggerConfig"
                )
        if self.beta_schedule not in SCHEDULES:
            raise ConfigError(
                "beta_schedule", f"must be one of {', '.join(SCHEDULES)}, got {self.beta_schedule!r}", owner="DAggerConfig"
            )
        for name in ("rounds", "episodes_per_round"):
            if getattr(self, name) < 1:
                raise ConfigError(name, f"must be at least 1, got {getattr(self, name)}", owner="DAggerConfig")
        if not 0.0 <= self.beta_decay <= 1.0:
            raise ConfigError("beta_decay", f"must be in [0, 1], got {self.beta_decay}", owner="DAggerConfig")
