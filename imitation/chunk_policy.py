"""Action chunking (Zhao et al. 2023, ACT, without its CVAE latent; docs/THEORY.md §5.4): the policy
kind "chunk" of `imitation.policy_kinds`, a policy of the last n observations that predicts the
next H actions at once,

    (â_t, …, â_{t+H−1}) = f_θ(s_{t−n+1}, …, s_t),

an MLP on the n observations (normalised, side by side; an angle θ read as (cos θ, sin θ)
where `--angles` says). BC fits it to the demos' windows
(`imitation.data.windows`) by the L1 error of each predicted action, in standardised units for Box
actions (loss "mse": the squared error), or the cross-entropy of each step's class for Discrete
ones, averaged over the entries that lie inside the episode (m_{t,k} = 1 − pad_{t,k}):

    ℓ_θ = Σ_{t,k} m_{t,k} |â_{t+k} − a_{t+k}|₁ / Σ_{t,k} m_{t,k}  +  c_2 · ||θ||²

Acting, it executes the first k of a chunk's H actions, then plans again from the n latest
observations (receding horizon; k = H executes whole chunks). With temporal ensembling (ACT) it
plans at every step and executes, for Box actions, the weighted mean of what every chunk still
covering step t planned for it, the i-th oldest weighted w_i = exp(−m·i):

    a_t = Σ_i w_i â_t^{(i)} / Σ_i w_i.

Before the episode's n-th step its first observation stands in for the missing ones, as in
training. `reset` forgets the history and the plans when an episode starts.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch
from torch import nn

from imitation.data.loader import TransitionTensors
from imitation.data.spaces import space_from_json
from imitation.data.windows import WindowBatch
from imitation.errors import ImitationError
from imitation.limits import LIMITS, over_limit
from imitation.mlp import hidden_layers, mlp_weight_count, orthogonal_linear
from imitation.policies import action_logits_size
from imitation.policy_protocol import ImitationObjective, MomentsMerge, PolicyConfig
from imitation.sequence_policy import SequencePolicy, step_features
from imitation.tensors import TensorTree


def _sizes(config: PolicyConfig) -> tuple[int, int]:
    """(inputs, outputs) of the network: n flat observations in, H action heads out."""
    features, actions = step_features(config, "chunk"), space_from_json(config.action_space)
    if not isinstance(actions, (gym.spaces.Box, gym.spaces.Discrete)):
        raise ImitationError(f"the chunk policy predicts Box or Discrete actions, not {type(actions).__name__}")
    return config.history * features, config.chunk * action_logits_size(actions)


def planned_weights(config: PolicyConfig) -> int:
    """The weights a chunk policy of `config` holds (its biases and statistics not counted)."""
    inputs, outputs = _sizes(config)
    return mlp_weight_count(inputs, config.hidden_sizes, outputs)


class ActionChunking(SequencePolicy):
    """The module docstring's f_θ, with its observation and action statistics, and the plan it is executing."""

    action_mean: torch.Tensor  # buffers, declared for the type checker
    action_scale: torch.Tensor
    kind = "chunk"

    def __init__(self, config: PolicyConfig) -> None:
        super().__init__(config)
        if config.previous_action:
            raise ImitationError("the chunk policy is not conditioned on the previous action; leave --previous-action off")
        if config.ensemble is not None and not isinstance(self.action_space, gym.spaces.Box):
            raise ImitationError("temporal ensembling averages Box actions; a Discrete one executes its chunks (--execute)")
        inputs, outputs = _sizes(config)
        if (weights := planned_weights(config)) > LIMITS.policy_parameters:
            raise over_limit(f"chunk policy parameters ({inputs} inputs, {outputs} outputs)", weights, "policy_parameters")
        self.steps = self.config.chunk
        self.width = outputs // self.steps  # one step's action (Box) or logits (Discrete)
        hidden = config.hidden_sizes[-1] if config.hidden_sizes else inputs
        self.trunk = hidden_layers(inputs, config.hidden_sizes, config.activation)
        self.head = orthogonal_linear(hidden, outputs, 0.01)
        self.register_buffer("action_mean", torch.zeros(self.width if self.is_continuous else 0))
        self.register_buffer("action_scale", torch.ones(self.width if self.is_continuous else 0))
        if config.ensemble is not None:
            self.execute = 1
        self._plans: list[np.ndarray] = []  # (batch, H, …) env actions, oldest first; the newest is executed
        self._done = 0  # actions of the newest plan executed

    # -- the network -------------------------------------------------------------------------------

    def _chunk(self, history: TensorTree, noise: float = 0.0) -> torch.Tensor:
        """f_θ on a batch of histories (batch, n, *observation shape), their normalised numbers
        noised by σ = `noise`: (batch, H, width)."""
        features = self.observed(history, noise)
        return self.head(self.trunk(features)).reshape(len(features), self.steps, self.width)

    def _env_actions(self, chunk: torch.Tensor) -> torch.Tensor:
        """A chunk of head outputs → env actions (Box: back to the env's units; Discrete: the likeliest class)."""
        if self.is_continuous:
            assert isinstance(self.action_space, gym.spaces.Box)
            actions = self.action_mean + self.action_scale * chunk
            return actions.reshape(*chunk.shape[:2], *self.action_space.shape)
        assert isinstance(self.action_space, gym.spaces.Discrete)
        return chunk.argmax(-1) + int(self.action_space.start)

    # -- training ----------------------------------------------------------------------------------

    def imitation_loss(
        self, batch: TransitionTensors | WindowBatch, objective: ImitationObjective
    ) -> tuple[torch.Tensor, torch.Tensor]:
        batch, observations = self.windows(batch)
        predicted = self._chunk(observations, self.training_noise(objective))
        inside = (~batch.action_pad).float()
        if self.is_continuous:
            target = (batch.actions.reshape(*predicted.shape).float() - self.action_mean) / self.action_scale
            error = predicted - target
            per_step = (error**2 if objective.loss == "mse" else error.abs()).sum(-1)
        else:
            assert isinstance(self.action_space, gym.spaces.Discrete)
            classes = batch.actions.long().reshape(-1) - int(self.action_space.start)
            per_step = nn.functional.cross_entropy(predicted.reshape(-1, self.width), classes, reduction="none")
            per_step = per_step.reshape(inside.shape)
        fit = (per_step * inside).sum() / inside.sum()
        loss = fit
        if objective.l2_coef:
            loss = loss + objective.l2_coef * sum((parameter**2).sum() for parameter in self.parameters())
        return loss, fit

    def fit_action_normalizer(self, actions: torch.Tensor, observations: object, *, merge: MomentsMerge | None = None) -> None:
        """Box actions: the head's units standardised by the training actions' mean and std per
        dimension (a dimension that never moves keeps scale 1)."""
        if not self.is_continuous:
            return
        with torch.no_grad():
            flat = actions.reshape(len(actions), -1).double()
            mean, std = flat.mean(0), flat.std(0, unbiased=False)
            if merge is not None:
                mean, std = merge(len(flat), mean, std)
            self.action_mean.copy_(mean)
            self.action_scale.copy_(torch.where(std > 1e-6, std, torch.ones_like(std)))

    # -- acting ------------------------------------------------------------------------------------

    def point_action(self, observations: TensorTree) -> torch.Tensor:
        """The first action of the chunk planned from each observation alone (as at an episode's
        first step, the observation standing in for the history)."""
        first = self._env_actions(self._chunk(self.first_step_history(observations)))[:, 0]
        return first.reshape(len(first), -1) if self.is_continuous else first

    def predict(self, observations: np.ndarray | dict, *, deterministic: bool = True) -> np.ndarray:
        """The next action of each row: its plan's, planning again every `execute` actions, or
        the ensemble of every plan that covers this step."""
        if self._history.push(self.acting_rows(observations)):
            self._plans = []
        if not self._plans or self._done >= self.execute:
            with torch.no_grad():
                history = torch.as_tensor(self._history.rows, device=self.action_mean.device)
                plan = self._env_actions(self._chunk(history)).cpu().numpy()
            # Ensembling keeps the H latest plans (one per step): the oldest covers this step with its last action.
            kept = self._plans[max(0, len(self._plans) - self.steps + 1) :] if self.config.ensemble is not None else []
            self._plans = [*kept, plan]
            self._done = 0
        if self.config.ensemble is None:
            action = self._plans[-1][:, self._done]
        else:
            ages = len(self._plans) - 1 - np.arange(len(self._plans))  # steps since each plan was made
            weights = np.exp(-self.config.ensemble * np.arange(len(self._plans)))
            planned = np.stack([plan[:, age] for plan, age in zip(self._plans, ages)])
            action = np.tensordot(weights, planned, axes=1) / weights.sum()
        self._done += 1
        if self.is_continuous:
            assert isinstance(self.action_space, gym.spaces.Box)
            return np.clip(action, self.action_space.low, self.action_space.high).astype(self.action_space.dtype)
        return action.astype(np.int64)

    def reset(self) -> None:
        self._history.clear()
        self._plans, self._done = [], 0
