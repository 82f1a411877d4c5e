"""Actor-critic MLP policies shared by PPO, BC and DAgger, the policy kind "actor-critic" of
`imitation.policy_kinds` (softmax and Gaussian policies: docs/THEORY.md §2.3–2.4), and the
pieces that act with a policy in an env.

Three policy heads, chosen by the action space:

- Discrete actions: a categorical (softmax) policy, π(a|s) = softmax(f(s))_a.
- MultiDiscrete actions: one independent categorical per component, π(a|s) = Π_i softmax(f_i(s))_{a_i}.
- Box actions: a diagonal Gaussian with a state-independent log-std,
  π(a|s) = Π_i N(a_i; μ_i(s), σ_i²), σ = exp(log_std); actions sent to the env are clipped to
  the space bounds, while log-probs are of the unclipped sample (as in CleanRL and SB3).

The heads index classes 0 … n-1; a space with `start` ≠ 0 takes env actions a = index + start,
so env actions (from demos, experts, the env) go through `from_env_action` before log π is taken
and policy actions through `to_env_action` before the env sees them.

A Gaussian policy may also be conditioned on the previous action (`previous_action`, for
command streams; `imitation.envs.previous_action`): it observes x_t = [s_t, a_{t-1}, 1{t=0}]
and predicts the change of the command, μ(x_t) = a_{t-1} + f(x_t), so that holding the last
command is where it starts and what it must improve on.

Image observations (uint8 frames, `imitation.envs.pixels`) and Dict observations that mix them
with vectors are encoded as SB3's MultiInputPolicy does: each image leaf (a stack of
`frame_stack` frames) through its own CNN (`imitation.encoders`), the vector leaves flattened,
normalised and concatenated beside them; actor and critic share the CNN. `observation_keys`
picks the leaves a policy reads (a pixel policy ignores the state recorded beside its frames).

Observations go through an optional running mean/std normaliser that is part of the module
(saved with the weights), so evaluation sees exactly what training saw. Discrete observations
are one-hot encoded. Weights use orthogonal initialisation: gain √2 for hidden layers, 0.01 for
the policy head (near-uniform initial policy), 1 for the value head.
"""

from __future__ import annotations

import math
from typing import Any, Protocol, cast

import gymnasium as gym
import numpy as np
import torch
from torch import nn
from torch.distributions import Categorical, Distribution, Normal, kl_divergence, register_kl

from imitation.data.frame_transform import FrameTransform, TransformFrames
from imitation.data.loader import TransitionTensors
from imitation.data.spaces import check_spaces_fit, describe_space, space_from_json, space_to_json
from imitation.data.windows import WindowBatch
from imitation.encoders import ImageEncoder, cnn_weight_count, conv_output_sides, random_shift
from imitation.envs.make import make_env
from imitation.envs.pixels import (
    PixelObservation,
    PixelRecipe,
    StackFrames,
    make_pixel_env,
)
from imitation.envs.previous_action import PreviousActionObservation
from imitation.envs.rollout import start_episode
from imitation.errors import ImitationError
from imitation.limits import LIMITS, over_limit
from imitation.mlp import (
    ACTIVATIONS,
    hidden_layers,
    mlp_weight_count,
    orthogonal_linear,
)
from imitation.observation_encoding import (
    ImageLeaf,
    check_cnn_size,
    leaf_frames,
    observation_size,
    vector_leaves,
)
from imitation.policy_protocol import ImitationObjective, ImitationPolicy, MomentsMerge, PolicyConfig

_SCALAR_SHAPE = torch.Size()  # the default sample_shape of Distribution.sample (immutable)


class RunningMeanStd(nn.Module):
    """Running mean and variance of a stream of batches (Chan et al.'s parallel update).

    Kept as buffers so they are saved with the model and follow it to its device."""

    # Buffers (register_buffer): declared for the type checker, which otherwise sees nn.Module.__getattr__.
    mean: torch.Tensor
    var: torch.Tensor
    count: torch.Tensor

    def __init__(self, shape: tuple[int, ...], epsilon: float = 1e-4) -> None:
        super().__init__()
        self.epsilon = epsilon
        self.register_buffer("mean", torch.zeros(shape, dtype=torch.float64))
        self.register_buffer("var", torch.ones(shape, dtype=torch.float64))
        self.register_buffer("count", torch.tensor(epsilon, dtype=torch.float64))

    def reset_parameters(self) -> None:
        """Forget everything seen (before fitting the statistics of a new data set)."""
        self.mean.zero_()
        self.var.fill_(1.0)
        self.count.fill_(self.epsilon)

    def update(self, batch: torch.Tensor) -> None:
        """Fold in a batch, in pieces of at most 2^23 numbers: the float64 copy the statistics
        need stays small however large the batch (a whole demo set, when BC fits them)."""
        rows = batch.reshape(-1, *self.mean.shape)
        step = max(1, 2**23 // max(1, self.mean.numel()))
        for start in range(0, len(rows), step):
            self._update(rows[start : start + step])

    def _update(self, batch: torch.Tensor) -> None:
        with torch.no_grad():
            batch = batch.to(torch.float64)
            batch_mean, batch_var, batch_count = batch.mean(0), batch.var(0, unbiased=False), batch.shape[0]
            delta = batch_mean - self.mean
            total = self.count + batch_count
            self.mean += delta * batch_count / total
            self.var.copy_(
                (self.var * self.count + batch_var * batch_count + delta**2 * self.count * batch_count / total) / total
            )
            self.count.copy_(total)

    def normalize(self, x: torch.Tensor, clip: float = 10.0) -> torch.Tensor:
        scaled = (x - self.mean.to(x.dtype)) / torch.sqrt(self.var.to(x.dtype) + 1e-8)
        return scaled.clamp(-clip, clip)


class SoftmaxCategorical(Categorical):
    """Categorical(logits) normalised by log_softmax, one kernel, where torch's constructor takes
    logsumexp, a composite of several: on a PPO minibatch, each kernel's dispatch is most of its cost."""

    def __init__(self, logits: torch.Tensor) -> None:
        self.logits = torch.log_softmax(logits, -1)
        self._param = self.logits
        self._num_events = self.logits.size()[-1]
        Distribution.__init__(self, self.logits.size()[:-1], validate_args=False)


class MultiCategorical(Distribution):
    """Independent categoricals over the components of a MultiDiscrete action: the logits of
    component i are columns sizes[0] + … + sizes[i-1] onward; log-probs and entropies add up."""

    arg_constraints: dict = {}

    def __init__(self, logits: torch.Tensor, sizes: list[int]) -> None:
        self.parts = [SoftmaxCategorical(part) for part in torch.split(logits, sizes, dim=-1)]
        super().__init__(batch_shape=logits.shape[:-1], validate_args=False)

    @property
    def mode(self) -> torch.Tensor:
        return torch.stack([part.probs.argmax(-1) for part in self.parts], -1)

    def sample(self, sample_shape: torch.Size | list[int] | tuple[int, ...] = _SCALAR_SHAPE) -> torch.Tensor:
        return torch.stack([part.sample(sample_shape) for part in self.parts], -1)

    # sum() over the (non-empty) parts is a Tensor; typeshed's sum() also allows its start value 0.
    def log_prob(self, value: torch.Tensor) -> torch.Tensor:
        return cast(torch.Tensor, sum(part.log_prob(value[..., i]) for i, part in enumerate(self.parts)))

    def entropy(self) -> torch.Tensor:
        return cast(torch.Tensor, sum(part.entropy() for part in self.parts))


@register_kl(MultiCategorical, MultiCategorical)
def _multi_categorical_kl(p: MultiCategorical, q: MultiCategorical) -> torch.Tensor:
    return cast(torch.Tensor, sum(kl_divergence(a, b) for a, b in zip(p.parts, q.parts)))


def action_logits_size(space: gym.Space) -> int:
    """Width of the action head for a Discrete, MultiDiscrete or Box action space."""
    if isinstance(space, gym.spaces.Discrete):
        return int(space.n)
    if isinstance(space, gym.spaces.MultiDiscrete):
        return int(space.nvec.sum())
    return observation_size(space)


def _check_size(inputs: int, hidden_sizes: list[int], outputs: int, *, shared: bool) -> None:
    """Refuse, before any weight is allocated, a network beyond `LIMITS.policy_parameters`
    (a forged space of 2^23 inputs would otherwise ask for gigabytes of weights)."""
    widths = [inputs, *hidden_sizes]
    trunk = sum((a + 1) * b for a, b in zip(widths, widths[1:]))
    parameters = trunk * (1 if shared else 2) + (widths[-1] + 1) * (outputs + 1)
    if parameters > LIMITS.policy_parameters:
        raise over_limit(
            f"policy parameters ({inputs} inputs, hidden {hidden_sizes}, {outputs} outputs)", parameters, "policy_parameters"
        )


class ActorCritic(ImitationPolicy):
    """An MLP actor (categorical, multi-categorical or Gaussian head) and critic, with separate or
    shared trunks: the policy kind "actor-critic"."""

    # Buffers (register_buffer) of MultiDiscrete and Box actions respectively, declared for the type checker.
    action_start: torch.Tensor
    action_low: torch.Tensor
    action_high: torch.Tensor
    action_mean: torch.Tensor  # with normalize_actions
    action_scale: torch.Tensor

    def __init__(self, config: PolicyConfig) -> None:
        if config.activation not in ACTIVATIONS:
            raise ImitationError(f"activation must be one of {sorted(ACTIVATIONS)}, got {config.activation!r}")
        if config.history != 1 or config.chunk != 1:
            raise ImitationError(
                f"the actor-critic reads one observation and predicts one action, not {config.history} and "
                f"{config.chunk}: train sequences with --policy chunk"
            )
        if config.angles:
            raise ImitationError(
                "--angles is read by the sequence policies (chunk, diffusion); the actor-critic reads observations as they are"
            )
        super().__init__(config)
        self.layout = config.layout(self.observation_space)
        encoders = self._image_encoders()
        self.image_encoders = nn.ModuleList(encoders)
        obs_size = (
            observation_size(self.observation_space)
            if self.layout is None
            else sum(encoder.features for encoder in encoders) + self.layout.vector_size
        )
        normalized_size = obs_size if self.layout is None else self.layout.vector_size
        hidden = config.hidden_sizes[-1] if config.hidden_sizes else obs_size
        known = isinstance(
            self.action_space, (gym.spaces.Discrete, gym.spaces.MultiDiscrete, gym.spaces.Box)
        )  # others are refused below
        _check_size(
            obs_size, config.hidden_sizes, action_logits_size(self.action_space) if known else 0, shared=config.shared_trunk
        )
        self.obs_rms = RunningMeanStd((normalized_size,)) if config.normalize_observations and normalized_size else None
        # Pixels standardised per channel by the demos' statistics: a rendered scene is mostly one
        # background value, and /255 alone leaves the moving parts a small dent in a field of ones.
        self.pixel_rms = (
            nn.ModuleList(RunningMeanStd((leaf.channels,)) for leaf in self.layout.images)
            if config.normalize_observations and self.layout is not None and self.layout.images
            else None
        )
        self.actor_trunk = hidden_layers(obs_size, config.hidden_sizes, config.activation)
        self.critic_trunk = (
            self.actor_trunk if config.shared_trunk else hidden_layers(obs_size, config.hidden_sizes, config.activation)
        )
        self.value_head = orthogonal_linear(hidden, 1, 1.0)
        # Component sizes of a MultiDiscrete action (None for the other spaces).
        self.action_sizes: list[int] | None = None
        if isinstance(self.action_space, gym.spaces.Discrete):
            self.is_continuous = False
            self.action_head = orthogonal_linear(hidden, int(self.action_space.n), 0.01)
        elif isinstance(self.action_space, gym.spaces.MultiDiscrete):
            if self.action_space.nvec.ndim != 1:
                raise ImitationError(
                    f"policies take MultiDiscrete actions of one dimension, not of shape {self.action_space.nvec.shape}"
                )
            self.is_continuous = False
            self.action_sizes = [int(n) for n in self.action_space.nvec]
            self.action_head = orthogonal_linear(hidden, sum(self.action_sizes), 0.01)
            self.register_buffer("action_start", torch.as_tensor(self.action_space.start, dtype=torch.int64), persistent=False)
        elif isinstance(self.action_space, gym.spaces.Box):
            self.is_continuous = True
            action_dim = int(np.prod(self.action_space.shape))
            self.action_head = orthogonal_linear(hidden, action_dim, 0.01)
            self.log_std = nn.Parameter(torch.full((action_dim,), float(config.log_std_init)))
            self.register_buffer("action_low", torch.as_tensor(self.action_space.low, dtype=torch.float32).reshape(-1))
            self.register_buffer("action_high", torch.as_tensor(self.action_space.high, dtype=torch.float32).reshape(-1))
            if config.normalize_actions:
                self.register_buffer("action_mean", torch.zeros(action_dim))
                self.register_buffer("action_scale", torch.ones(action_dim))
        else:
            raise ImitationError(
                f"policies take Discrete, MultiDiscrete or Box actions, not {type(self.action_space).__name__}"
            )
        # Columns of the raw observation that hold a_{t-1} (x_t's last column is the first-step flag).
        self.inputs = obs_size
        self.previous_columns = slice(0, 0)
        if config.previous_action:
            action_dim = int(np.prod(self.action_space.shape or ())) if self.is_continuous else 0
            if (
                not self.is_continuous
                or self.layout is not None
                or not isinstance(self.observation_space, gym.spaces.Box)
                or obs_size < action_dim + 2
            ):
                raise ImitationError(
                    "a policy of the previous action takes Box actions and Box observations [state, previous action, "
                    f"first-step flag], not {type(self.action_space).__name__} actions and {self.observation_space}"
                )
            self.previous_columns = slice(obs_size - action_dim - 1, obs_size - 1)

    def _image_encoders(self) -> list[ImageEncoder]:
        if self.layout is None:
            return []
        cnn = self.config.cnn_config()
        check_cnn_size(self.layout, cnn)
        encoders = []
        for leaf in self.layout.images:
            if min(conv_output_sides(leaf.height, leaf.width, cnn)) < 1:
                raise ImitationError(
                    f"{leaf.height}×{leaf.width} frames are too small for the CNN (kernels {cnn.kernels}, strides "
                    f"{cnn.strides}): give larger frames or smaller kernels"
                )
            encoders.append(ImageEncoder(leaf.frames, leaf.height, leaf.width, leaf.channels, cnn))
        return encoders

    # -- observations ---------------------------------------------------------------------------

    def _frames(self, observations: Any, leaf: ImageLeaf) -> torch.Tensor:
        return leaf_frames(observations, leaf)

    def _vector(self, observations: Any) -> torch.Tensor:
        assert self.layout is not None
        return vector_leaves(observations, self.layout)

    def shifted(self, observations: Any, pad: int) -> Any:
        """The batch with each image leaf randomly shifted by up to `pad` pixels (`random_shift`)."""
        if self.layout is None or not self.layout.images or pad <= 0:
            return observations
        if not isinstance(observations, dict):
            return random_shift(self._frames(observations, self.layout.images[0]), pad).reshape(observations.shape)
        shifted = dict(observations)
        for leaf in self.layout.images:
            (key,) = leaf.path
            shifted[key] = random_shift(self._frames(observations, leaf), pad).reshape(observations[key].shape)
        return shifted

    def encode(self, observations: Any) -> torch.Tensor:
        """Raw observations (batch first) → flat float features, normalised if configured."""
        if self.layout is not None:
            parts = [encoder(self._scaled_frames(observations, index)) for index, encoder in enumerate(self.image_encoders)]
            if self.layout.vectors:
                vector = self._vector(observations)
                parts.append(self.obs_rms.normalize(vector) if self.obs_rms is not None else vector)
            return torch.cat(parts, dim=1)
        if isinstance(self.observation_space, gym.spaces.Discrete):
            index = observations.long().reshape(-1) - int(self.observation_space.start)
            return nn.functional.one_hot(index, int(self.observation_space.n)).float()
        flat = observations.reshape(observations.shape[0], -1).float()
        features = self.obs_rms.normalize(flat) if self.obs_rms is not None else flat
        if self.config.previous_action:  # a_{t-1} rides along, raw, for the Gaussian's mean
            return torch.cat([features, flat[:, self.previous_columns]], dim=1)
        return features

    def _scaled_frames(self, observations: Any, index: int) -> torch.Tensor:
        """Image leaf `index` of a batch as float (batch, k, H, W, C): standardised per channel
        with `normalize_observations`, else scaled to [0, 1]."""
        assert self.layout is not None
        frames = self._frames(observations, self.layout.images[index]).float()
        pixels = self.pixel_statistics
        return pixels[index].normalize(frames) if pixels else frames / 255.0

    @property
    def pixel_statistics(self) -> list[RunningMeanStd]:
        """Each image leaf's pixel statistics (none without `normalize_observations`)."""
        return [cast(RunningMeanStd, statistics) for statistics in self.pixel_rms or []]

    @property
    def observation_normalizers(self) -> list[RunningMeanStd]:
        """The statistics `update_normalizer` fits: the vector leaves' and each image leaf's."""
        return [*([self.obs_rms] if self.obs_rms is not None else []), *self.pixel_statistics]

    def update_normalizer(self, observations: Any) -> None:
        if self.obs_rms is not None:
            flat = self._vector(observations) if self.layout is not None else observations.reshape(observations.shape[0], -1)
            self.obs_rms.update(flat)
        if self.layout is not None:
            for leaf, statistics in zip(self.layout.images, self.pixel_statistics):
                # The newest frame of each stack: every stored frame counted once.
                statistics.update(self._frames(observations, leaf)[:, -1])

    def fit_action_normalizer(self, actions: torch.Tensor, observations: Any, *, merge: MomentsMerge | None = None) -> None:
        """Standardise the Gaussian head's units by the mean and std per dimension of what it
        predicts (a dimension that never moves keeps scale 1): these actions, or with
        `previous_action` their changes a_t − a_{t-1}. Nothing to do without `normalize_actions`.
        `merge(count, mean, std)` turns these rows' moments into those of all the rows, where
        other processes hold the rest (data-parallel training)."""
        if not (self.is_continuous and self.config.normalize_actions):
            return
        with torch.no_grad():
            flat = actions.reshape(actions.shape[0], -1).double()
            if self.config.previous_action:
                flat = flat - observations.reshape(observations.shape[0], -1)[:, self.previous_columns].double()
            mean, std = flat.mean(0), flat.std(0, unbiased=False)
            if merge is not None:
                mean, std = merge(len(flat), mean, std)
            self.action_mean.copy_(mean)
            self.action_scale.copy_(torch.where(std > 1e-6, std, torch.ones_like(std)))

    # -- the policy -------------------------------------------------------------------------------

    def distribution(self, features: torch.Tensor) -> Distribution:
        """π(·|s) for encoded observations: Categorical(logits), MultiCategorical or Normal(μ, σ) per action dim."""
        if self.config.previous_action:
            parameters = self.action_head(self.actor_trunk(features[:, : self.inputs]))
            return self.distribution_from(parameters, previous=features[:, self.inputs :])
        return self.distribution_from(self.action_head(self.actor_trunk(features)))

    def distribution_from(
        self, parameters: torch.Tensor, log_std: torch.Tensor | None = None, *, previous: torch.Tensor | None = None
    ) -> Distribution:
        """π(·|s) from the action head's output (the Gaussian's σ from `log_std`, by default the
        policy's own; its mean shifted by the `previous` action for a policy of it)."""
        # No argument validation: it costs more than the network on small batches.
        if self.is_continuous:
            std = (self.log_std if log_std is None else log_std).exp().expand_as(parameters)
            mean, scale = parameters, std
            if self.config.normalize_actions:  # the head's units are standardised: back to the env's
                mean, scale = self.action_mean + self.action_scale * parameters, self.action_scale * std
            return Normal(mean if previous is None else previous + mean, scale, validate_args=False)
        if self.action_sizes is not None:
            return MultiCategorical(parameters, self.action_sizes)
        return SoftmaxCategorical(parameters)

    def log_prob(self, distribution: Distribution, actions: torch.Tensor) -> torch.Tensor:
        """log π(a|s) of the policy's own action values (class indices, not env actions: see
        `from_env_action`); for the Gaussian, the sum over action dimensions."""
        if self.is_continuous:
            return distribution.log_prob(actions.reshape(actions.shape[0], -1)).sum(-1)
        if self.action_sizes is not None:
            return distribution.log_prob(actions.long().reshape(actions.shape[0], -1))
        return distribution.log_prob(actions.long().reshape(-1))

    def env_action_log_prob(self, distribution: Distribution, env_actions: torch.Tensor) -> torch.Tensor:
        """log π of the action the env received. Box actions are clipped to the bounds, so the
        Gaussian N(μ, σ) puts a probability mass Φ((low − μ)/σ) on `low` itself (1 − Φ((high − μ)/σ)
        on `high`): at a bound the log of that mass stands in for the log-density (a censored
        Gaussian), which is what makes saturated actions, e.g. a demo's full torque, comparable."""
        if not self.is_continuous:
            return self.log_prob(distribution, self.from_env_action(env_actions))
        actions = env_actions.reshape(env_actions.shape[0], -1).float()
        assert isinstance(distribution, Normal)
        below = torch.special.log_ndtr((self.action_low - distribution.mean) / distribution.stddev)
        above = torch.special.log_ndtr((distribution.mean - self.action_high) / distribution.stddev)
        log_probs = torch.where(
            actions <= self.action_low, below, torch.where(actions >= self.action_high, above, distribution.log_prob(actions))
        )
        return log_probs.sum(-1)

    def entropy(self, distribution: Distribution) -> torch.Tensor:
        """H[π(·|s)]; for the Gaussian and MultiDiscrete, the sum over action dimensions."""
        entropy = distribution.entropy()
        return entropy.sum(-1) if self.is_continuous else entropy

    def log_prob_and_entropy(self, distribution: Distribution, actions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.log_prob(distribution, actions), self.entropy(distribution)

    def sample(self, features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Sample a ~ π(·|s) for a rollout: (action, log π(a|s), distribution parameters).

        Written out rather than through torch.distributions, whose per-call overhead is several
        times the network's cost on a rollout's small batches. The parameters are the Gaussian
        mean or the normalised logits (log-probabilities), enough to rebuild π_k(·|s)."""
        if self.config.previous_action:
            raise ImitationError("a policy of the previous action is trained by BC; PPO's rollouts do not sample it")
        with torch.no_grad():
            out = self.action_head(self.actor_trunk(features))
            if self.is_continuous:
                noise = torch.randn_like(out)
                action = out + self.log_std.exp() * noise
                log_prob = (-0.5 * noise**2 - self.log_std - 0.5 * math.log(2 * math.pi)).sum(-1)
                return action, log_prob, out
            if self.action_sizes is not None:
                parts = [torch.log_softmax(part, -1) for part in torch.split(out, self.action_sizes, dim=-1)]
                action = torch.cat([torch.multinomial(part.exp(), 1) for part in parts], -1)
                log_prob = cast(
                    torch.Tensor, sum(part.gather(-1, action[:, i : i + 1]).squeeze(-1) for i, part in enumerate(parts))
                )
                return action, log_prob, torch.cat(parts, -1)
            log_probs = torch.log_softmax(out, -1)
            action = torch.multinomial(log_probs.exp(), 1).squeeze(-1)
            return action, log_probs.gather(-1, action[:, None]).squeeze(-1), log_probs

    def value(self, features: torch.Tensor) -> torch.Tensor:
        trunk_input = features[:, : self.inputs] if self.config.previous_action else features
        return self.value_head(self.critic_trunk(trunk_input)).squeeze(-1)

    def act(self, features: torch.Tensor, *, deterministic: bool = False) -> torch.Tensor:
        """An action a ~ π(·|s), or its mode: the policy's own action values (see `to_env_action`)."""
        distribution = self.distribution(features)
        return distribution.mode if deterministic else distribution.sample()

    def from_env_action(self, actions: torch.Tensor) -> torch.Tensor:
        """Env actions (e.g. from demos) → the policy's own action values, for log π(a|s)."""
        if self.is_continuous:
            return actions.float()
        if self.action_sizes is not None:
            return actions.long().reshape(actions.shape[0], -1) - self.action_start
        assert isinstance(self.action_space, gym.spaces.Discrete)
        return actions.long() - int(self.action_space.start)

    def to_env_action(self, actions: torch.Tensor) -> np.ndarray:
        """Policy actions → what env.step takes: Box actions clipped to the bounds and shaped."""
        if self.is_continuous:
            assert isinstance(self.action_space, gym.spaces.Box)
            clipped = torch.clamp(actions, self.action_low, self.action_high)
            return clipped.cpu().numpy().astype(self.action_space.dtype).reshape(-1, *self.action_space.shape)
        if self.action_sizes is not None:
            return (actions.long() + self.action_start).cpu().numpy().astype(self.action_space.dtype)
        assert isinstance(self.action_space, gym.spaces.Discrete)
        return actions.cpu().numpy().astype(np.int64) + int(self.action_space.start)

    def predict(self, observations: Any, *, deterministic: bool = True) -> np.ndarray:
        """Env actions for a batch of raw observations (numpy), e.g. for evaluation or as an expert."""
        with torch.no_grad():
            tensors = tensor_tree(observations, self.action_head.weight.device)
            return self.to_env_action(self.act(self.encode(tensors), deterministic=deterministic))

    # -- as an imitation policy (`ImitationPolicy`) --------------------------------------------------

    def imitation_loss(
        self, batch: TransitionTensors | WindowBatch, objective: ImitationObjective
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """BC's objective for this kind (docs/THEORY.md §5),

            −log π_θ(a|s)  (or, with loss "mse", ||μ_θ(s) − a||²)  −  c_H · H[π_θ(·|s)]  +  c_2 · ||θ_actor||²,

        the NLL that of the categorical(s) over the class index of the demo's action or of the
        Gaussian; the L2 term over the actor's trunk and head. In training, image observations are
        randomly shifted first."""
        if not isinstance(batch, TransitionTensors):
            raise ImitationError("the actor-critic trains on single transitions, not windows of them")
        assert isinstance(batch.actions, torch.Tensor)  # a policy takes no Dict actions
        observations = self.shifted(batch.observations, objective.random_shift) if self.training else batch.observations
        distribution = self.distribution(self.encode(observations))
        if objective.loss == "mse":
            fit = ((distribution.mean - batch.actions.reshape(len(batch), -1).float()) ** 2).sum(-1).mean()
        else:
            fit = -self.log_prob(distribution, self.from_env_action(batch.actions)).mean()
        loss = fit
        if objective.entropy_coef:
            loss = loss - objective.entropy_coef * self.entropy(distribution).mean()
        if objective.l2_coef:
            l2 = sum(
                (parameter**2).sum()
                for name, parameter in self.named_parameters()
                if name.startswith(("actor_trunk", "action_head"))
            )
            loss = loss + objective.l2_coef * l2
        return loss, fit

    def point_action(self, observations: Any) -> torch.Tensor:
        return self._point(self.distribution(self.encode(observations)))

    def _point(self, distribution: Distribution) -> torch.Tensor:
        """The Gaussian's mean (unclipped), or the most likely class as an env action."""
        if self.is_continuous:
            return distribution.mean
        if self.action_sizes is not None:
            return distribution.mode + self.action_start
        assert isinstance(self.action_space, gym.spaces.Discrete)
        return distribution.mode + int(self.action_space.start)

    def action_nll(self, observations: Any, actions: torch.Tensor) -> torch.Tensor:
        return -self.log_prob(self.distribution(self.encode(observations)), self.from_env_action(actions))

    def held_out(self, observations: Any, actions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        distribution = self.distribution(self.encode(observations))  # one forward pass (a CNN's is most of it)
        return self._point(distribution), -self.log_prob(distribution, self.from_env_action(actions))

    @property
    def reads_images(self) -> bool:
        return len(self.image_encoders) > 0


def tensor_tree(observations: Any, device: torch.device | str = "cpu") -> Any:
    """A batch of raw observations (an array, or a dict of them) as tensors on `device`."""
    if isinstance(observations, dict):
        return {key: tensor_tree(value, device) for key, value in observations.items()}
    return torch.as_tensor(np.asarray(observations), device=device)


def batch_of_one(observation: Any) -> Any:
    """One observation (an array, or a dict of them) as a batch of one."""
    if isinstance(observation, dict):
        return {key: batch_of_one(value) for key, value in observation.items()}
    return np.asarray(observation)[None]


def require_flat_observations(policy: ActorCritic, learner: str) -> ActorCritic:
    """`policy`, refused in one line when it reads image or Dict observations, which `learner`
    (policy gradient, the policy searches) does not train yet: its rollout buffers hold flat features."""
    if policy.layout is not None:
        raise ImitationError(
            f"{learner} takes Box or Discrete observations, not {describe_space(policy.observation_space)}; "
            "image and Dict observations are learnt by train bc, train dagger, train ppo and train irl --method gcl"
        )
    return policy


def make_policy(observation_space: gym.Space, action_space: gym.Space, **options: Any) -> ActorCritic:
    config = PolicyConfig(
        observation_space=space_to_json(observation_space), action_space=space_to_json(action_space), **options
    )
    return ActorCritic(config)


class Predictor(Protocol):
    """What acts in an env from a batch of raw observations: an ActorCritic, or an expert read
    from elsewhere (an SB3 zip's off-policy network)."""

    observation_space: gym.Space
    action_space: gym.Space

    def predict(self, observations: Any, *, deterministic: bool = True) -> np.ndarray: ...

    def eval(self) -> Any: ...


class SingleObservationPolicy:
    """Adapts a policy to the expert interface: one raw observation → one env action."""

    def __init__(self, policy: Predictor, *, deterministic: bool = True) -> None:
        self.policy = policy.eval()
        self.deterministic = deterministic
        if getattr(policy, "layout", None) is None:
            # One observation at a time through an MLP: extra threads only synchronise, and on busy
            # cores they wait for each other (bench/single_observation_threads.py). Learners set
            # their own count when they start.
            torch.set_num_threads(1)

    def __call__(self, observation: Any) -> Any:
        action = self.policy.predict(batch_of_one(observation), deterministic=self.deterministic)[0]
        return int(action) if isinstance(self.policy.action_space, gym.spaces.Discrete) else action

    def reset(self) -> None:
        start_episode(self.policy)


POLICY_PREFIX = "policy."


def policy_tensors(policy: ImitationPolicy) -> dict[str, torch.Tensor]:
    """The policy's weights and normaliser statistics, named for model.safetensors."""
    return {POLICY_PREFIX + name: tensor for name, tensor in policy.state_dict().items()}


def planned_weights(config: PolicyConfig) -> int:
    """The weights an `ActorCritic` of `config` holds, counted from its MLP and CNN shapes
    without building it (a forged config is refused before anything is allocated)."""
    observations, actions = space_from_json(config.observation_space), space_from_json(config.action_space)
    outputs = action_logits_size(actions)
    trunks = 1 if config.shared_trunk else 2
    layout = config.layout(observations)
    cnn = config.cnn_config()
    inputs = observation_size(observations) if layout is None else layout.vector_size + cnn.features * len(layout.images)
    planned = trunks * mlp_weight_count(inputs, config.hidden_sizes, 0) + (config.hidden_sizes or [inputs])[-1] * (outputs + 1)
    if layout is not None:
        planned += sum(cnn_weight_count(leaf.frames * leaf.channels, leaf.height, leaf.width, cnn) for leaf in layout.images)
    return planned


def acting_env(policy: ImitationPolicy, env: gym.Env) -> gym.Env:
    """`env` as `policy` observes it: with x_t = [s_t, a_{t-1}, 1{t=0}] for a policy of the
    previous action, its image leaves cropped and resized as the policy's demos were
    (`TransformFrames`), then stacked for a policy of frame stacks (`env` renders the frames
    already: `make_acting_env`)."""
    if policy.config.image_transform is not None:
        env = TransformFrames(env, FrameTransform.from_json(policy.config.image_transform))
    if policy.config.frame_stack > 1:
        env = StackFrames(env, policy.config.frame_stack)
    return PreviousActionObservation(env) if policy.config.previous_action else env


def make_acting_env(config: PolicyConfig, env_id: str) -> gym.Env:
    """The env `env_id` made as a policy of `config` needs it before `acting_env`: rendering
    frames (`PixelObservation`) for a policy trained on rendered frames."""
    if config.pixels is None:
        return make_env(env_id)
    return make_pixel_env(env_id, PixelRecipe.from_json(config.pixels))


def observed_rendering(policy: ImitationPolicy, rendered: gym.Env) -> gym.Env:
    """An env made with render_mode="rgb_array" (for a video) as `policy` observes it: its
    rendered frames for a policy trained on them, then `acting_env`."""
    pixels = policy.config.pixels
    return acting_env(policy, PixelObservation(rendered, PixelRecipe.from_json(pixels)) if pixels is not None else rendered)


def check_policy_fits_env(policy: Predictor, env: gym.Env, where: str) -> None:
    """One-line error when a saved policy was trained for other spaces than env's."""
    check_spaces_fit("policy's", policy.observation_space, policy.action_space, env, where=where)
