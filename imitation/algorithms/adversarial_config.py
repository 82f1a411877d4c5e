"""GAIL's and AIRL's settings (`AdversarialConfig`), flags of `train irl --method gail|airl`
(imitation.flags). Light, like bc_config, for `train irl --help`."""

from __future__ import annotations

from dataclasses import dataclass, field

from imitation.algorithms.gcl_config import REWARD_INPUTS
from imitation.errors import ConfigError
from imitation.flags import finite, flag, hidden_sizes, seed

METHODS = ("gail", "airl")
GAIL_REWARDS = ("softplus", "logit")
# The settings of the discriminator's training, which a method without one refuses.
DISCRIMINATOR_TRAINING = ("discriminator_steps", "policy_updates", "pool_rollouts", "latest_share", "gradient_penalty")


@dataclass(kw_only=True)
class AdversarialConfig:
    method: str = "gail"
    # The discriminator's inputs (GAIL) or the recovered reward g's (AIRL): None for the method's
    # own, "sa" for GAIL and "s" for AIRL (a reward of the state alone is what transfers).
    inputs: str | None = flag(
        None,
        name="--reward-inputs",
        choices=REWARD_INPUTS,
        help="what the reward reads, the state s, its action a and next state s'",
        default_text="s for airl, sa for gail's discriminator",
    )
    hidden_sizes: list[int] = flag(
        name="--hidden",
        parse=hidden_sizes,
        metavar="32,32",
        help="discriminator MLP widths, or 'linear'",
        default_factory=lambda: [64, 64],
    )
    # AIRL's shaping potential h(s).
    potential_hidden_sizes: list[int] = field(default_factory=lambda: [64, 64])
    learning_rate: float = flag(3e-4, name="--lr", metavar="LR", help="Adam learning rate of the discriminator")
    batch_size: int = 256
    discriminator_steps: int = flag(8, metavar="N", help="discriminator minibatch steps per round")
    policy_updates: int = flag(1, metavar="N", help="PPO updates per round, between the discriminator's steps")
    pool_rollouts: int = flag(
        1, metavar="N", help="the discriminator's negatives are the policy's last N rollouts", default_text="1, the latest"
    )
    # ρ: the share of each minibatch's policy steps drawn from the latest rollout, the rest from the pool.
    latest_share: float = flag(
        0.0,
        parse=finite,
        metavar="RHO",
        help="the share of the discriminator's negatives drawn from the latest rollout, the rest from the whole pool "
        "of --pool-rollouts",
    )
    gradient_penalty: float = flag(
        0.0, parse=finite, metavar="L", help="weight of E‖∇_x logit D‖² over the discriminator's inputs"
    )
    # GAIL: PPO's reward, "softplus" −log(1 − D) or "logit" log D − log(1 − D) (`imitation.algorithms.gail`).
    gail_reward: str = flag(
        "softplus",
        choices=GAIL_REWARDS,
        help="the reward PPO optimises under gail, softplus −log(1 − D) (Ho & Ermon) or logit log D − log(1 − D), which "
        "does not flatten where the discriminator wins",
    )
    # AIRL: α of PPO's reward f − α log π(a|s); 1 makes it log D − log(1 − D) exactly.
    policy_entropy: float = 1.0
    seed: int = flag(0, parse=seed, metavar="S", help="seed")

    def validate(self) -> None:
        if self.method not in METHODS:
            raise ConfigError("method", f"must be one of {', '.join(METHODS)}, got {self.method!r}", owner="AdversarialConfig")
        if self.inputs is not None and self.inputs not in REWARD_INPUTS:
            raise ConfigError(
                "inputs", f"must be one of {', '.join(REWARD_INPUTS)}, got {self.inputs!r}", owner="AdversarialConfig"
            )
        if self.gail_reward not in GAIL_REWARDS:
            raise ConfigError(
                "gail_reward", f"must be one of {', '.join(GAIL_REWARDS)}, got {self.gail_reward!r}", owner="AdversarialConfig"
            )
        for name in ("batch_size", "discriminator_steps", "policy_updates", "pool_rollouts"):
            if getattr(self, name) < 1:
                raise ConfigError(name, f"must be at least 1, got {getattr(self, name)}", owner="AdversarialConfig")
        if not 0 < self.learning_rate < 1e30:  # NaN fails too; from ~1e37 Adam's step overflows float32
            raise ConfigError(
                "learning_rate", f"must be a positive number below 1e30, got {self.learning_rate}", owner="AdversarialConfig"
            )
        if not 0 <= self.latest_share <= 1:
            raise ConfigError("latest_share", f"must be in [0, 1], got {self.latest_share}", owner="AdversarialConfig")
        for name in ("gradient_penalty", "policy_entropy"):
            if not 0 <= getattr(self, name) < float("inf"):
                raise ConfigError(name, f"must be a finite number ≥ 0, got {getattr(self, name)}", owner="AdversarialConfig")

    @property
    def reward_inputs(self) -> str:
        return self.inputs or ("sa" if self.method == "gail" else "s")
