"""PPO's settings (`PPOConfig`); the `train ppo` flags are those of its fields declared with
`flag` (imitation.flags). Light, like bc_config, for `train ppo --help`."""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import TYPE_CHECKING, Any

from imitation.errors import ConfigError
from imitation.flags import flag, seed

if TYPE_CHECKING:
    from imitation.envs.pixels import PixelRecipe

OBJECTIVES = ("clip", "kl")


@dataclass(kw_only=True)
class PPOConfig:
    """Hyperparameters; per-environment presets are in `imitation.jobs.presets`."""

    env_id: str = flag(name="--env", metavar="ID", help="gymnasium environment id")
    total_steps: int = flag(100_000, name="--steps", metavar="N", help="PPO's environment steps in total")
    objective: str = flag("clip", choices=OBJECTIVES, help="clipped surrogate or adaptive KL penalty")
    n_envs: int = flag(4, metavar="K", help="parallel environments", default_text="per env")
    n_steps: int = 128
    batch_size: int = 128
    n_epochs: int = 4
    gamma: float = 0.99
    gae_lambda: float = 0.95
    learning_rate: float = 2.5e-4
    anneal_lr: bool = True
    clip_range: float = 0.2
    clip_value_loss: bool = False
    value_coef: float = 0.5
    entropy_coef: float = 0.0
    max_grad_norm: float = 0.5
    target_kl: float | None = None
    kl_target: float = 0.01
    kl_beta_init: float = 1.0
    normalize_advantages: bool = True
    normalize_observations: bool = False
    normalize_rewards: bool = False
    hidden_sizes: list[int] = field(default_factory=lambda: [64, 64])
    activation: str = "tanh"
    shared_trunk: bool = False
    log_std_init: float = 0.0
    async_envs: bool = flag(False, name="--async", help="step the environments in subprocesses")
    # Image observations: how frames are rendered (a PixelRecipe's JSON; None: the env's own
    # observations), frames stacked per image leaf, the leaves the policy reads (None: the frames
    # alone with `pixels`, every leaf otherwise) and its CNN (encoders.CNNConfig; None: Nature CNN).
    pixels: dict[str, Any] | None = None
    frame_stack: int = flag(
        1,
        metavar="K",
        help="image observations (--pixels, or an env whose observations are images): frames stacked per image",
        default_text="the --reward's or the resumed run's, else 1",
    )
    observation_keys: list[str] | None = None
    cnn: dict[str, Any] | None = None
    seed: int = flag(0, parse=seed, metavar="S", help="seed for torch, the envs and sampling")
    device: str = flag("auto", metavar="auto|cpu|cuda", help="where the networks run")
    threads: int = flag(1, metavar="N", help="torch CPU threads", default_text="1, fastest for small networks")

    def validate(self) -> None:
        if self.objective not in OBJECTIVES:
            raise ConfigError(
                "objective", f"must be one of {', '.join(OBJECTIVES)}, got {self.objective!r}", owner="PPOConfig"
            )
        for name in ("total_steps", "n_envs", "n_steps", "batch_size", "n_epochs"):
            if getattr(self, name) < 1:
                raise ConfigError(name, f"must be at least 1, got {getattr(self, name)}", owner="PPOConfig")
        if self.total_steps < self.n_envs * self.n_steps:
            raise ConfigError(
                "total_steps",
                f"{self.total_steps} is less than one rollout ({self.n_envs} envs × {self.n_steps} steps)",
                owner="PPOConfig",
            )
        if not 0 < self.learning_rate < 1e30:  # NaN fails too; from ~1e37 Adam's step overflows float32
            raise ConfigError(
                "learning_rate", f"must be a positive number below 1e30, got {self.learning_rate}", owner="PPOConfig"
            )
        if not 1 <= self.frame_stack <= 64:
            raise ConfigError("frame_stack", f"must be in [1, 64], got {self.frame_stack}", owner="PPOConfig")
        if self.pixels is not None:
            from imitation.envs.pixels import PixelRecipe

            try:
                PixelRecipe.from_json(self.pixels)
            except ValueError as error:
                raise ConfigError("pixels", str(error), owner="PPOConfig") from None

    @property
    def recipe(self) -> PixelRecipe | None:
        """How the env's frames are rendered, None when it is observed as it is."""
        from imitation.envs.pixels import PixelRecipe

        return PixelRecipe.from_json(self.pixels) if self.pixels is not None else None

    @staticmethod
    def from_json(data: dict[str, Any]) -> PPOConfig:
        known = {f.name for f in fields(PPOConfig)}
        return PPOConfig(**{key: value for key, value in data.items() if key in known})
