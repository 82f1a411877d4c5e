"""What the sequence policy kinds (`chunk_policy`, `diffusion_policy`) share: windows of the last n
observations and the next H actions (`imitation.data.windows`), observations read as one flat
vector per step (a Box flattened; a Dict's Box and Discrete leaves side by side in key order,
Discrete ones one-hot, `--observation-keys` choosing the leaves), each angle as (cos θ, sin θ)
where `--angles` says, normalised by running statistics, and the history of observations they act
on, in which, before an episode's n-th step, its first observation stands in for the missing ones,
as the windows they were trained on pad them."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch

from imitation.data.loader import TransitionTensors
from imitation.data.spaces import space_from_json
from imitation.data.windows import WindowBatch, WindowSpec
from imitation.errors import ImitationError
from imitation.mlp import ACTIVATIONS
from imitation.observation_encoding import ObservationLayout, check_angles, observation_size, vector_leaves, with_angles
from imitation.policies import RunningMeanStd
from imitation.policy_protocol import ImitationObjective, ImitationPolicy, PolicyConfig
from imitation.tensors import TensorTree, tree_map


def step_features(config: PolicyConfig, kind: str) -> int:
    """The numbers one observation becomes (an angle two); ImitationError naming `kind` for
    observations that are not a flat Box or a Dict of Box and Discrete leaves."""
    observations = space_from_json(config.observation_space)
    layout = config.layout(observations)
    if layout is None and isinstance(observations, gym.spaces.Box):
        size = observation_size(observations)
    elif layout is not None and not layout.images and isinstance(observations, gym.spaces.Dict):
        size = layout.vector_size
    else:
        raise ImitationError(
            f"the {kind} policy reads Box observations or Dicts of Box and Discrete leaves, not {observations}"
        )
    check_angles(config.angles, size)
    return size + len(config.angles)


class ObservationHistory:
    """The n latest flat observations of each row; `push` adds a step's, `clear` starts an episode."""

    def __init__(self, length: int) -> None:
        self.length = length
        self.rows: np.ndarray | None = None  # (batch, n, features)

    def push(self, current: np.ndarray) -> bool:
        """Add the current observations, flat rows (batch, features); True when a new episode (or a
        batch of another size) started the history afresh."""
        if self.rows is None or len(self.rows) != len(current):
            self.rows = np.repeat(current[:, None], self.length, axis=1)
            return True
        self.rows = np.concatenate([self.rows[:, 1:], current[:, None]], axis=1)
        return False

    def clear(self) -> None:
        self.rows = None


class SequencePolicy(ImitationPolicy):
    """A policy of n observations and H actions: its windows, observation statistics and history."""

    kind: str  # the registered name, for messages
    angle_index: torch.Tensor  # a buffer, declared for the type checker

    def __init__(self, config: PolicyConfig) -> None:
        super().__init__(config)
        if config.activation not in ACTIVATIONS:
            raise ImitationError(f"activation must be one of {sorted(ACTIVATIONS)}, got {config.activation!r}")
        self.obs_rms = RunningMeanStd((step_features(config, self.kind),))
        self.layout: ObservationLayout | None = config.layout(self.observation_space)
        # Made once, on the module's device; derived from the config, so not saved with the weights.
        self.register_buffer("angle_index", torch.tensor(config.angles, dtype=torch.long), persistent=False)
        self._history = ObservationHistory(config.history)
        # Actions of each plan executed before planning again.
        self.execute = config.execute or max(1, config.chunk // 2)

    @property
    def window(self) -> WindowSpec:
        return WindowSpec(self.config.history, self.config.chunk)

    def windows(self, batch: TransitionTensors | WindowBatch) -> tuple[WindowBatch, TensorTree]:
        """The batch, which must be windows (BC's loader gathers them for a sequence policy), and its observations."""
        if not isinstance(batch, WindowBatch):
            raise ImitationError(f"the {self.kind} policy trains on windows of the demos (its loader gathers them)")
        return batch, batch.observations

    def flat(self, observations: TensorTree, leading: int) -> torch.Tensor:
        """Observations whose first `leading` dimensions are batch (and history) as float rows of
        their numbers (a Dict's leaves side by side); a tensor of a Dict space is flat already
        (the acting history's rows)."""
        if self.layout is None or isinstance(observations, torch.Tensor):
            assert isinstance(observations, torch.Tensor)
            return observations.reshape(*observations.shape[:leading], -1).float()
        first = next(iter(observations.values()))
        batch = first.shape[:leading]
        rows = tree_map(lambda leaf: leaf.reshape(-1, *leaf.shape[leading:]), observations)
        return vector_leaves(rows, self.layout).reshape(*batch, -1)

    def acting_rows(self, observations: np.ndarray | dict) -> np.ndarray:
        """A batch of env observations as the flat rows the acting history holds."""
        if self.layout is None:
            return np.asarray(observations, dtype=np.float32).reshape(len(observations), -1)
        return self.flat(tree_map(torch.as_tensor, observations), 1).numpy()

    def first_step_history(self, observations: TensorTree) -> torch.Tensor:
        """Each observation alone as a history (batch, n, features), standing in for the steps
        before it, as at an episode's first step."""
        rows = self.flat(observations, 1)
        return rows.unsqueeze(1).expand(len(rows), self.config.history, rows.shape[-1])

    def observed(self, history: TensorTree, noise: float = 0.0) -> torch.Tensor:
        """A batch of histories (batch, n, *observation shape) as the network reads them: (batch, n · features);
        with `noise` σ, each normalised number plus σ z, z ~ N(0, 1) (training's augmentation)."""
        steps = with_angles(self.flat(history, 2), self.angle_index)
        features = self.obs_rms.normalize(steps).reshape(len(steps), -1)
        return features + noise * torch.randn_like(features) if noise else features

    def training_noise(self, objective: ImitationObjective) -> float:
        """The σ of the observation noise for a loss: the objective's while training, none when scored."""
        return objective.observation_noise if self.training else 0.0

    @property
    def observation_normalizers(self) -> list[RunningMeanStd]:
        return [self.obs_rms]

    def update_normalizer(self, observations: TensorTree) -> None:
        self.obs_rms.update(with_angles(self.flat(observations, 1), self.angle_index))
