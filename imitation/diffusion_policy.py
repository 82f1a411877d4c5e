"""Diffusion policy (Chi et al. 2023; docs/THEORY.md §5.5): the policy kind "diffusion" of
`imitation.policy_kinds`, a policy of the last n observations o that samples the next H actions
A = (a_t, …, a_{t+H−1}) by denoising, so that demonstrations that go two ways (left or right
around PushT's T) are two modes of the policy, not their average.

Actions are scaled to [−1, 1] per dimension by the training actions' range. Training (DDPM, Ho et
al. 2020) draws a step k ∈ {0, …, K−1} and noise ε ~ N(0, I) per window, noises the demo chunk A⁰,

    A^k = √ᾱ_k A⁰ + √(1 − ᾱ_k) ε,   ᾱ_k = Π_{i≤k} (1 − β_i)   (β: the squared-cosine schedule),

and fits the denoiser D_θ(A^k, k, o), an MLP on [A^k, o normalised (an angle θ read as (cos θ,
sin θ) where `--angles` says), a sinusoidal embedding of k], to its target y by the squared error
on every entry of the chunk (past an episode's end its last action stands in, as the Diffusion
Policy code pads):

    ℓ_θ = E_{k,ε} ||y − D_θ(A^k, k, o)||² / (H · d_a)  +  c_2 · ||θ||²,

with y = A⁰, the clean chunk (`prediction` "sample", `train bc`'s default: on PushT it covers more
of the goal than ε after the same training, bench/RESULTS.md), or y = ε, the noise (DDPM's,
"noise"). Either way the denoiser gives both estimates, the other from the noising equation:

    sample:  Â⁰ = D_θ,  ε̂ = (A^k − √ᾱ_k Â⁰) / √(1 − ᾱ_k);    noise:  ε̂ = D_θ,  Â⁰ = (A^k − √(1 − ᾱ_k) ε̂) / √ᾱ_k.

Acting, DDIM (Song et al. 2021) takes S of the K steps, k = K − 1, K − 1 − K/S, …, from
A^{K−1} ~ N(0, I), with Â⁰ clipped to [−1, 1]:

    A^{k'} = √ᾱ_{k'} Â⁰ + √(1 − ᾱ_{k'} − σ_k²) ε̂ + σ_k z,   z ~ N(0, I),
    σ_k = η √((1 − ᾱ_{k'}) / (1 − ᾱ_k)) √(1 − ᾱ_k / ᾱ_{k'})

for the next step k' = k − K/S (ᾱ_{k'} = 1 below 0). η = 0 is deterministic; η = 1 (`train bc`'s
default: on PushT it covers more of the goal than η = 0) adds the DDPM posterior's noise, so that
with S = K it is DDPM's ancestral sampling, as the Diffusion Policy paper acts. The first `execute`
actions of the last Â⁰ are executed before planning again (receding horizon). The schedules and
the DDIM step are diffusers' (`DDPMScheduler.add_noise`, `DDIMScheduler.step`).
With M > 1 `members` the denoiser is a deep ensemble: M MLPs D_θ_m from their own initial
weights, each fitted to the same noised chunks (ℓ the mean of their M errors), and sampling steps
from their mean prediction (1/M) Σ_m D_θ_m; validation scores that mean, as it acts.
The weights it acts with are an exponential moving average θ̄ ← λθ̄ + (1 − λ)θ after each update,
λ = min(0.9999, 1 − (1 + u)^(−3/4)) at update u (the Diffusion Policy code's EMA), kept with the
weights; validation and held-out scores use it too. The initial noise of each plan and the z of
its steps come from a generator seeded with 0 at every episode's start, so an episode replays
exactly from the env's seed.
"""

from __future__ import annotations

import copy
import math
from typing import Any

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
from imitation.policy_protocol import ImitationObjective, MomentsMerge, PolicyConfig
from imitation.sequence_policy import SequencePolicy, step_features
from imitation.tensors import TensorTree

STEP_FEATURES = 32  # the sinusoidal embedding of the diffusion step k
TARGETS = {"sample": "sample", "noise": "epsilon"}  # what the denoiser predicts: our name → diffusers' prediction_type
EMA_POWER, EMA_MAX = 0.75, 0.9999


def _sizes(config: PolicyConfig) -> tuple[int, int, int]:
    """(observation inputs, chunk numbers, one action's numbers) of the denoiser."""
    features, actions = step_features(config, "diffusion"), space_from_json(config.action_space)
    if not isinstance(actions, gym.spaces.Box):
        raise ImitationError(f"the diffusion policy samples Box actions, not {type(actions).__name__} ones")
    action = math.prod(actions.shape)
    return config.history * features, config.chunk * action, action


def planned_weights(config: PolicyConfig) -> int:
    """The weights a diffusion policy of `config` holds, its moving average included (biases and statistics not counted)."""
    observations, chunk, _ = _sizes(config)
    return 2 * config.members * mlp_weight_count(chunk + observations + STEP_FEATURES, config.hidden_sizes, chunk)


def step_embedding(steps: torch.Tensor, features: int = STEP_FEATURES) -> torch.Tensor:
    """[sin(k ω_i), cos(k ω_i)] with ω_i = 10000^(−i/(features/2 − 1)), i < features/2 (the Transformer's)."""
    half = features // 2
    frequencies = torch.exp(-math.log(10000.0) * torch.arange(half, device=steps.device) / (half - 1))
    angles = steps.float()[:, None] * frequencies[None]
    return torch.cat([angles.sin(), angles.cos()], dim=-1)


class Denoiser(nn.Module):
    """D_θ(A^k, k, o): an MLP on the noisy chunk, the normalised observations and k's embedding."""

    def __init__(self, observations: int, chunk: int, hidden_sizes: list[int], activation: str) -> None:
        super().__init__()
        inputs = chunk + observations + STEP_FEATURES
        self.trunk = hidden_layers(inputs, hidden_sizes, activation)
        self.head = orthogonal_linear(hidden_sizes[-1] if hidden_sizes else inputs, chunk, 1.0)

    def forward(self, noisy: torch.Tensor, steps: torch.Tensor, observations: torch.Tensor) -> torch.Tensor:
        return self.head(self.trunk(torch.cat([noisy, observations, step_embedding(steps)], dim=-1)))


class DenoiserEnsemble(nn.Module):
    """M denoisers side by side; their predictions stacked (M, batch, chunk)."""

    def __init__(self, members: list[Denoiser]) -> None:
        super().__init__()
        self.members = nn.ModuleList(members)

    def forward(self, noisy: torch.Tensor, steps: torch.Tensor, observations: torch.Tensor) -> torch.Tensor:
        return torch.stack([member(noisy, steps, observations) for member in self.members])


class DiffusionPolicy(SequencePolicy):
    """The module docstring's D_θ with its moving average, statistics, schedulers and current plan."""

    action_low: torch.Tensor  # buffers, declared for the type checker
    action_high: torch.Tensor
    updates: torch.Tensor
    kind = "diffusion"

    def __init__(self, config: PolicyConfig) -> None:
        super().__init__(config)
        from diffusers.schedulers.scheduling_ddim import DDIMScheduler
        from diffusers.schedulers.scheduling_ddpm import DDPMScheduler

        if config.previous_action or config.ensemble is not None:
            raise ImitationError(
                "the diffusion policy executes its plans (--execute); leave --previous-action and --ensemble off"
            )
        if config.prediction not in TARGETS:
            raise ImitationError(
                f"a diffusion policy's denoiser predicts one of {', '.join(TARGETS)}, not {str(config.prediction)[:40]!r}"
            )
        if config.sampling_steps > config.denoising_steps:
            raise ImitationError(
                f"the sampling steps ({config.sampling_steps}) are a subset of the denoising steps "
                f"({config.denoising_steps}): lower --sampling-steps or raise --denoising-steps"
            )
        observations, chunk, self.action_width = _sizes(config)
        if (weights := planned_weights(config)) > LIMITS.policy_parameters:
            raise over_limit(
                f"diffusion policy parameters ({observations} inputs, {chunk} outputs)", weights, "policy_parameters"
            )
        # One member keeps the layout runs written before `members` have.
        members = [Denoiser(observations, chunk, config.hidden_sizes, config.activation) for _ in range(config.members)]
        self.denoiser: Denoiser | DenoiserEnsemble = members[0] if len(members) == 1 else DenoiserEnsemble(members)
        self.average = copy.deepcopy(self.denoiser).requires_grad_(False)
        self.register_buffer("action_low", torch.full((self.action_width,), -1.0))
        self.register_buffer("action_high", torch.ones(self.action_width))
        self.register_buffer("updates", torch.zeros((), dtype=torch.long))
        schedule: dict[str, Any] = {
            "num_train_timesteps": config.denoising_steps,
            "beta_schedule": "squaredcos_cap_v2",
            "clip_sample": True,
            "prediction_type": TARGETS[config.prediction],
        }
        self.training_schedule = DDPMScheduler(**schedule)
        # Trailing spacing starts from the last noise level, K − 1, where A^K is pure noise (leading would start at K − K/S).
        self.sampler = DDIMScheduler(**schedule, timestep_spacing="trailing")
        self.sampler.set_timesteps(config.sampling_steps)
        self.noise = torch.Generator().manual_seed(0)
        self._plan: np.ndarray | None = None  # (batch, H, *action shape) env actions
        self._done = 0  # actions of the plan executed

    # -- units -------------------------------------------------------------------------------------

    def _range(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The middle of the training actions' range and its half-width, which 0 and ±1 stand for."""
        return (self.action_high + self.action_low) / 2, (self.action_high - self.action_low) / 2

    def _scaled(self, actions: torch.Tensor) -> torch.Tensor:
        """Env actions (batch, H, …) → the [−1, 1] units the chunk is denoised in, flat per window."""
        middle, half = self._range()
        flat = actions.reshape(len(actions), self.config.chunk, self.action_width).float()
        return ((flat - middle) / half).reshape(len(actions), -1)

    def _env_actions(self, scaled: torch.Tensor) -> torch.Tensor:
        assert isinstance(self.action_space, gym.spaces.Box)
        middle, half = self._range()
        chunk = scaled.reshape(len(scaled), self.config.chunk, self.action_width)
        return (middle + half * chunk).reshape(len(scaled), self.config.chunk, *self.action_space.shape)

    @property
    def _acting(self) -> Denoiser | DenoiserEnsemble:
        """The weights that act and are scored: the moving average, once training has updated any."""
        return self.average if int(self.updates) > 0 and not self.training else self.denoiser

    def _predictions(self, noisy: torch.Tensor, steps: torch.Tensor, conditioning: torch.Tensor) -> torch.Tensor:
        """Every member's prediction (M, batch, chunk) by the weights that act."""
        denoiser = self._acting
        predicted = denoiser(noisy, steps, conditioning)
        return predicted if isinstance(denoiser, DenoiserEnsemble) else predicted.unsqueeze(0)

    # -- training ----------------------------------------------------------------------------------

    def imitation_loss(
        self, batch: TransitionTensors | WindowBatch, objective: ImitationObjective
    ) -> tuple[torch.Tensor, torch.Tensor]:
        batch, observations = self.windows(batch)
        clean = self._scaled(batch.actions)
        noise = torch.randn_like(clean)
        steps = torch.randint(0, self.config.denoising_steps, (len(clean),), device=clean.device)
        noisy = self.training_schedule.add_noise(clean, noise, steps)
        predicted = self._predictions(noisy, steps, self.observed(observations, self.training_noise(objective)))
        target = clean if self.config.prediction == "sample" else noise
        # Training fits each member; a score is of their mean, which acts.
        fit = ((predicted - target) ** 2).mean() if self.training else ((predicted.mean(0) - target) ** 2).mean()
        loss = fit
        if objective.l2_coef:
            loss = loss + objective.l2_coef * sum((parameter**2).sum() for parameter in self.denoiser.parameters())
        return loss, fit

    def after_update(self) -> None:
        """Fold the updated weights into their moving average."""
        self.updates += 1
        decay = min(EMA_MAX, 1.0 - (1.0 + int(self.updates)) ** -EMA_POWER)
        with torch.no_grad():
            for average, current in zip(self.average.parameters(), self.denoiser.parameters()):
                average.lerp_(current, 1.0 - decay)

    def fit_action_normalizer(self, actions: torch.Tensor, observations: object, *, merge: MomentsMerge | None = None) -> None:
        """The training actions' range per dimension, which [−1, 1] stands for (a dimension that
        never moves spans ±1 around its value). Data-parallel runs pool it from each process's
        mean ± √3·std, the range of a uniform with those moments."""
        with torch.no_grad():
            flat = actions.reshape(len(actions), -1).double()
            low, high = flat.min(0).values, flat.max(0).values
            if merge is not None:
                mean, std = merge(len(flat), (low + high) / 2, (high - low) / (2 * math.sqrt(3)))
                low, high = mean - math.sqrt(3) * std, mean + math.sqrt(3) * std
            flat_range = (high - low) < 1e-6
            self.action_low.copy_(torch.where(flat_range, low - 1, low))
            self.action_high.copy_(torch.where(flat_range, high + 1, high))

    # -- acting ------------------------------------------------------------------------------------

    def sample(self, history: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
        """Chunks (batch, H, …) of env actions denoised by DDIM from noise drawn from `generator`."""
        conditioning = self.observed(history)
        generator = generator or self.noise
        chunk = torch.randn(
            (len(history), self.config.chunk * self.action_width), generator=generator, dtype=torch.float32
        ).to(conditioning.device)
        eta = float(self.config.sampling_noise)
        for step in self.sampler.timesteps:
            steps = torch.full((len(chunk),), int(step), device=chunk.device, dtype=torch.long)
            predicted = self._predictions(chunk, steps, conditioning).mean(0)
            chunk = self.sampler.step(predicted, int(step), chunk, eta=eta, generator=generator).prev_sample
        return self._env_actions(chunk.clamp(-1, 1))

    def point_action(self, observations: TensorTree) -> torch.Tensor:
        """The first action of a chunk sampled from each observation alone (standing in for the
        history), with noise of a fixed seed so that held-out scores repeat."""
        first = self.sample(self.first_step_history(observations), torch.Generator().manual_seed(0))[:, 0]
        return first.reshape(len(first), -1)

    def predict(self, observations: np.ndarray | dict, *, deterministic: bool = True) -> np.ndarray:
        """The next action of each row, from the plan sampled every `execute` actions."""
        if self._history.push(self.acting_rows(observations)):
            self._plan = None
        if self._plan is None or self._done >= self.execute:
            with torch.no_grad():
                history = torch.as_tensor(self._history.rows, device=self.action_low.device)
                self._plan = self.sample(history).cpu().numpy()
            self._done = 0
        action = self._plan[:, self._done]
        self._done += 1
        assert isinstance(self.action_space, gym.spaces.Box)
        return np.clip(action, self.action_space.low, self.action_space.high).astype(self.action_space.dtype)

    def reset(self) -> None:
        self._history.clear()
        self._plan, self._done = None, 0
        self.noise.manual_seed(0)
