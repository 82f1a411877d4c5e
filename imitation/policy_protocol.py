"""What the imitation learners and the tools around them need of a policy (`ImitationPolicy`),
and the config that rebuilds one (`PolicyConfig`).

BC trains it: `imitation_loss` on a batch of demo transitions, after its observation (and action)
normalisers are fitted to the demos. DAgger retrains it each round and acts with it. `eval
policy`, `record --expert RUN_DIR` and BC's evaluation act with it through `predict` (a batch of
raw observations → env actions), calling `reset` at each episode's start. BC scores it on
held-out demos by `point_action` (its single best guess) and, where it has a likelihood,
`action_nll`. The run directory keeps its `PolicyConfig` (under "policy" in config.json) and its
state dict (model.safetensors, `imitation.policies.policy_tensors`); sweeps see only the rows a
learner logs. A policy kind is a subclass plus an entry in `imitation.policy_kinds`.

`imitation.policies.ActorCritic` is the kind BC, DAgger, PPO and the other learners train today.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np
import torch
from torch import nn

from imitation.data.frame_transform import FrameTransform
from imitation.data.loader import TransitionTensors
from imitation.data.spaces import space_from_json
from imitation.data.windows import MAX_WINDOW, WindowBatch, WindowSpec
from imitation.mlp import check_layer_widths
from imitation.observation_encoding import ObservationConfig

if TYPE_CHECKING:
    from imitation.policies import RunningMeanStd

# (rows, mean, std) of one process's rows → (mean, std) of every process's (data-parallel training).
MomentsMerge = Callable[[int, torch.Tensor, torch.Tensor], tuple[torch.Tensor, torch.Tensor]]

ACTOR_CRITIC = "actor-critic"
MAX_MEMBERS = 64  # denoisers of a diffusion policy's ensemble: bounds a crafted config's loops
MAX_DENOISING_STEPS = 10_000  # far beyond the 100 of the Diffusion Policy paper; bounds a crafted config's loops


@dataclass(kw_only=True)
class PolicyConfig(ObservationConfig):
    """Everything needed to rebuild a policy before loading its weights: its kind, its spaces,
    how it reads observations (`ObservationConfig`, and the crop and size its frames are brought
    to), and the network options (what a kind does not use it ignores)."""

    # The registered kind (`imitation.policy_kinds`); run directories written before kinds existed hold actor-critics.
    kind: str = ACTOR_CRITIC
    observation_space: dict[str, Any]
    action_space: dict[str, Any]
    hidden_sizes: list[int] = field(default_factory=lambda: [64, 64])
    activation: str = "tanh"
    shared_trunk: bool = False
    normalize_observations: bool = False
    log_std_init: float = 0.0
    # Box actions: the Gaussian's head works in standardised units (fixed statistics, fitted to
    # the training actions by BC and saved with the weights), so every action dimension is learnt
    # at one scale whatever its units.
    normalize_actions: bool = False
    # Box actions: the observation is x_t = [s_t, a_{t-1}, 1{t=0}] and μ is a_{t-1} plus the head's output.
    previous_action: bool = False
    # Camera frames: the crop and size they are brought to, as the demos' were when loaded
    # (`acting_env`, `FrameTransform.to_json`).
    image_transform: dict[str, Any] | None = None
    # Sequence policies: the observations a policy reads (the current one and those before it),
    # the actions it predicts at once, and how many of them it executes before planning again
    # (None: the kind's default).
    history: int = 1
    chunk: int = 1
    execute: int | None = None
    # Temporal ensembling (ACT): plan every step and execute the weighted mean of every chunk's
    # action for it, weight exp(−m·i) for the i-th oldest (None: the receding horizon above).
    ensemble: float | None = None
    # Flat observations: the positions holding angles (radians), read as (cos, sin) by the sequence kinds.
    angles: list[int] = field(default_factory=list)
    # Diffusion policies: the noise levels of training (K), the denoising steps taken when acting
    # (S ≤ K), DDIM's η (the noise each of them adds), and what the denoiser predicts, the noise ε
    # or the clean chunk A⁰. The last two default to what runs written before they were settings
    # did: deterministic steps (η = 0) from a predicted noise.
    denoising_steps: int = 100
    sampling_steps: int = 10
    sampling_noise: float = 0.0
    prediction: str = "noise"
    # Diffusion policies: the denoisers of a deep ensemble (1: one denoiser, as runs written before).
    members: int = 1

    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    @staticmethod
    def from_json(data: dict[str, Any]) -> PolicyConfig:
        """From config.json's "policy"; TypeError or ValueError for anything malformed."""
        if not isinstance(data, dict):
            raise TypeError(f"the policy config is a {type(data).__name__}, not an object")
        config = PolicyConfig(**data)
        if not isinstance(config.kind, str):
            raise TypeError(f"the policy kind must be a name, got {str(config.kind)[:40]}")
        check_layer_widths(config.hidden_sizes)
        if not (
            isinstance(config.activation, str)
            and isinstance(config.shared_trunk, bool)
            and isinstance(config.normalize_observations, bool)
            and isinstance(config.normalize_actions, bool)
            and isinstance(config.previous_action, bool)
        ):
            raise TypeError(
                "activation must be a name, shared_trunk, normalize_observations/actions and previous_action true or false"
            )
        config.check_observation_fields()
        if config.image_transform is not None:
            FrameTransform.from_json(config.image_transform)
        for name in ("history", "chunk"):
            value = getattr(config, name)
            if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= MAX_WINDOW:
                raise ValueError(f"{name} must be a whole number in [1, {MAX_WINDOW}], got {str(value)[:40]}")
        if isinstance(config.members, bool) or not isinstance(config.members, int) or not 1 <= config.members <= MAX_MEMBERS:
            raise ValueError(f"members must be a whole number in [1, {MAX_MEMBERS}], got {str(config.members)[:40]}")
        for name in ("denoising_steps", "sampling_steps"):
            value = getattr(config, name)
            if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= MAX_DENOISING_STEPS:
                raise ValueError(f"{name} must be a whole number in [1, {MAX_DENOISING_STEPS}], got {str(value)[:40]}")
        if not (
            isinstance(config.angles, list)
            and len(config.angles) <= 1024
            and all(isinstance(i, int) and not isinstance(i, bool) and 0 <= i < 2**31 for i in config.angles)
            and len(set(config.angles)) == len(config.angles)
        ):
            raise ValueError(f"angles must be a list of distinct observation positions, got {str(config.angles)[:40]}")
        if isinstance(config.sampling_noise, bool) or not (
            isinstance(config.sampling_noise, (int, float)) and 0 <= config.sampling_noise <= 1
        ):
            raise ValueError(f"sampling_noise must be a number in [0, 1], got {str(config.sampling_noise)[:40]}")
        if not isinstance(config.prediction, str):
            raise TypeError(f"prediction must be a name, got {str(config.prediction)[:40]}")
        if config.sampling_steps > config.denoising_steps:
            raise ValueError(
                f"sampling_steps ({config.sampling_steps}) must be at most denoising_steps ({config.denoising_steps})"
            )
        if config.execute is not None and not (
            isinstance(config.execute, int) and not isinstance(config.execute, bool) and 1 <= config.execute <= config.chunk
        ):
            raise ValueError(f"execute must be a whole number in [1, chunk = {config.chunk}], got {str(config.execute)[:40]}")
        if config.ensemble is not None and (
            isinstance(config.ensemble, bool)
            or not isinstance(config.ensemble, (int, float))
            or not 0 <= config.ensemble < 1e3
        ):
            raise ValueError(f"ensemble must be a weight in [0, 1000), got {str(config.ensemble)[:40]}")
        if (
            isinstance(config.log_std_init, bool)
            or not isinstance(config.log_std_init, (int, float))
            or not math.isfinite(config.log_std_init)
        ):
            raise ValueError(f"log_std_init must be a finite number, got {config.log_std_init!r}")
        return config


@dataclass(frozen=True)
class ImitationObjective:
    """The settings of BC's objective a kind's `imitation_loss` reads: the fit ("nll", the
    negative log-likelihood of the demo's action, or "mse", the squared error of the policy's
    action), an entropy bonus and an L2 penalty on the actor's weights (coefficients), the
    random shift of training frames in pixels, and the σ of the Gaussian noise a sequence kind
    adds to its normalised training observations."""

    loss: str = "nll"
    entropy_coef: float = 0.0
    l2_coef: float = 0.0
    random_shift: int = 0
    observation_noise: float = 0.0


class ImitationPolicy(nn.Module, ABC):
    """A policy BC can train and every tool can act with (the module docstring). A kind
    implements the abstract methods; the others default to a policy without normalisers, without
    a likelihood and without memory between steps."""

    is_continuous: bool

    def __init__(self, config: PolicyConfig) -> None:
        super().__init__()
        self.config = config
        self.observation_space = space_from_json(config.observation_space)
        self.action_space = space_from_json(config.action_space)
        self.is_continuous = isinstance(self.action_space, gym.spaces.Box)

    @property
    def window(self) -> WindowSpec | None:
        """For a sequence policy, the observations it reads and the actions it predicts at once:
        BC trains it on windows of the demos of these lengths (`imitation.data.windows`); None
        (the default) for a policy of single transitions."""
        return None

    @abstractmethod
    def imitation_loss(
        self, batch: TransitionTensors | WindowBatch, objective: ImitationObjective
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """(the loss to minimise, its fit term alone) on a batch of demo transitions, or of
        windows for a policy of a longer `window`; random training-time augmentation only in
        training mode."""

    @abstractmethod
    def point_action(self, observations: Any) -> torch.Tensor:
        """The policy's single best guess of the env action for each raw observation of a batch
        (tensors): a Gaussian's mean, a categorical's mode; what BC's held-out squared error and
        error rate score."""

    @abstractmethod
    def predict(self, observations: Any, *, deterministic: bool = True) -> np.ndarray:
        """Env actions for a batch of raw observations (numpy), as env.step takes them."""

    def action_nll(self, observations: Any, actions: torch.Tensor) -> torch.Tensor | None:
        """−log π(a|s) per row of the env actions `actions` (None for a kind without a likelihood)."""
        return None

    def held_out(self, observations: Any, actions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        """(`point_action`, `action_nll`) of a batch, what BC scores it by; a kind whose two share
        a forward pass overrides this to run it once."""
        return self.point_action(observations), self.action_nll(observations, actions)

    def after_update(self) -> None:
        """Called after each optimiser step of BC (a moving average of the weights folds them in here)."""

    def reset(self) -> None:
        """Forget the episode so far (a new one starts): nothing, for a policy of the current observation alone."""

    @property
    def reads_images(self) -> bool:
        """Whether it runs a CNN on frames (learners then give it every core and smaller pieces)."""
        return False

    @property
    def observation_normalizers(self) -> list[RunningMeanStd]:
        """The statistics `update_normalizer` fits, reset before BC fits them again."""
        return []

    def update_normalizer(self, observations: Any) -> None:
        """Fold a batch of training observations into the normalisers' statistics."""

    def fit_action_normalizer(self, actions: torch.Tensor, observations: Any, *, merge: MomentsMerge | None = None) -> None:
        """Fit the action statistics to all the training actions (`merge` pools them across
        data-parallel processes)."""
