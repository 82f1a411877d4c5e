"""Adversarial imitation on PPO's loop (docs/THEORY.md §8.5): a discriminator D(s, a, s') trained
to tell demo steps (label 1) from the policy's (label 0), and PPO on a reward made of D. What D
is, which reward PPO optimises and which reward is exported are the method's (`imitation.algorithms.gail`,
`imitation.algorithms.airl`); the loop and D's loss are shared:

    ℓ(D) = −E_demos[log D] − E_negatives[log(1 − D)] + λ E‖∇_x logit D‖²,

the negatives being the policy's steps: a share ρ (`latest_share`) of them drawn from the latest
rollout and the rest from the pool, the last `pool_rollouts` rollouts; x every input the
discriminator's networks read (demo and policy steps alike), and λ `gradient_penalty`. A pool of
many rollouts keeps the early policies' steps among the negatives, so that a recovered reward
still rates them low; ρ keeps the current policy's steps, whose reward PPO optimises, among them.
`discriminator_steps` minibatch steps (`batch_size` demo steps and as many policy steps each) are
taken every `policy_updates` PPO updates: that pair is the discriminator/generator update ratio.

The loop, one `AdversarialImitation.step` per PPO update:

    τ ← rollout of π_k                                       (PPO.collect_rollout)
    pool ← the last `pool_rollouts` rollouts, τ among them
    every `policy_updates` updates: `discriminator_steps` steps on ℓ(D), ρ of the negatives from τ
    PPO update on the method's reward of τ                    (PPO.update)

The state saved with PPO's is D, its Adam state, the pool and the minibatch generator's position,
so an interrupted run resumes exactly.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
import torch
from torch import nn

from imitation.algorithms.adversarial_config import AdversarialConfig
from imitation.algorithms.beside_ppo import BesidePPO, env_action_log_probs
from imitation.algorithms.ppo import PPO
from imitation.checkpoints import (
    CheckpointData,
    CheckpointWriter,
    flat_names,
    restore_optimizer,
    tree_of_names,
    unprefixed,
)
from imitation.data.loader import TransitionTensors
from imitation.envs.rollout import Rollout
from imitation.errors import ImitationError
from imitation.policies import ActorCritic
from imitation.rewards import RewardNet, flat_batch, tree_index
from imitation.tensors import TensorTree, tree_cat


@dataclass
class Steps:
    """A batch of steps as a discriminator reads them; `terminated` is 1.0 where s' ended the
    episode (no value, or potential, after it)."""

    observations: TensorTree
    env_actions: torch.Tensor
    next_observations: TensorTree
    terminated: torch.Tensor

    def select(self, index: torch.Tensor) -> Steps:
        return Steps(**{name: tree_index(getattr(self, name), index) for name in Steps.__dataclass_fields__})

    def cat(self, *others: Steps) -> Steps:
        return Steps(**{name: tree_cat(*(getattr(s, name) for s in (self, *others))) for name in Steps.__dataclass_fields__})

    def __len__(self) -> int:
        return len(self.env_actions)


class Discriminator(Protocol):
    """A method's D: its logit, the reward PPO optimises, the reward it exports."""

    # Whether the logit takes log π(a|s) (AIRL's does, GAIL's does not).
    uses_policy: bool

    def reward_nets(self) -> list[RewardNet]: ...

    def parameters(self) -> Any: ...

    def state_dict(self) -> dict[str, torch.Tensor]: ...

    def load_state_dict(self, state: dict[str, torch.Tensor]) -> Any: ...

    def train(self, mode: bool = True) -> Any: ...

    def logits(self, steps: Steps, log_pi: torch.Tensor | None, *, penalised: bool) -> tuple[torch.Tensor, list[torch.Tensor]]:
        """logit D of each step, and the input tensors it is differentiable in (requiring
        gradients when `penalised`)."""
        ...

    def policy_rewards(self, steps: Steps, log_pi: torch.Tensor | None) -> torch.Tensor:
        """The reward PPO optimises, one per step, without gradients."""
        ...

    def recovered_reward(self) -> RewardNet: ...


def discriminator_loss(demo_logits: torch.Tensor, sample_logits: torch.Tensor) -> torch.Tensor:
    """−mean log D over demo steps − mean log(1 − D) over pooled steps, from the logits
    (log D = −softplus(−logit), log(1 − D) = −softplus(logit)); the two halves weigh alike."""
    return nn.functional.softplus(-demo_logits).mean() + nn.functional.softplus(sample_logits).mean()


def input_gradient_penalty(logits: torch.Tensor, inputs: list[torch.Tensor]) -> torch.Tensor:
    """E‖∇_x logit‖² over the batch, x every input tensor the logit was computed from."""
    gradients = torch.autograd.grad(logits.sum(), inputs, create_graph=True)
    squared = torch.stack([gradient.pow(2).reshape(len(gradient), -1).sum(-1) for gradient in gradients]).sum(0)
    return squared.mean()


def rollout_steps(rollout: Rollout) -> Steps:
    """A rollout's steps, (T, n_envs) merged into one batch dimension."""
    return Steps(
        observations=flat_batch(rollout.observations, 2),
        env_actions=flat_batch(rollout.env_actions, 2),
        next_observations=flat_batch(rollout.next_observations, 2),
        terminated=rollout.terminated.reshape(-1).float(),
    )


def demo_steps(demos: TransitionTensors) -> Steps:
    if demos.next_observations is None:
        raise ImitationError(
            "adversarial imitation needs the demos' next observations (load them with next_observations=True)"
        )
    assert isinstance(demos.actions, torch.Tensor)  # a reward model takes no Dict actions
    return Steps(demos.observations, demos.actions, demos.next_observations, demos.terminated.float())


class DiscriminatorLearner:
    """D, its optimiser, the pool of recent rollouts and the minibatch steps on ℓ(D)."""

    def __init__(
        self, discriminator: Discriminator, demos: TransitionTensors, config: AdversarialConfig, *, fit_statistics: bool = True
    ) -> None:
        config.validate()
        self.discriminator = discriminator
        # False for a discriminator started from a saved one: its weights were fitted to its own statistics.
        self.fit_statistics = fit_statistics
        self.demos = demo_steps(demos)
        self.config = config
        self.optimizer = torch.optim.Adam(discriminator.parameters(), lr=config.learning_rate)
        self.rollouts: list[Steps] = []
        self.generator = torch.Generator().manual_seed(config.seed)
        self.learned = 0  # rounds of discriminator steps so far
        self.last: dict[str, float] = {}  # the last round's statistics, logged until the next round

    def add_rollout(self, rollout: Rollout) -> Steps:
        """Pool the rollout's steps (a CPU copy), dropping the oldest beyond `pool_rollouts`; the steps."""
        steps = rollout_steps(rollout.cpu_copy())
        if not self.rollouts and self.fit_statistics:
            # Where the space is unbounded, the first policy's states widen the demos' spread.
            for net in self.discriminator.reward_nets():
                if net.config.normalize_observations:
                    demos, samples = self.demos.observations, steps.observations
                    # Statistics are of Box observations (RewardNet).
                    assert isinstance(demos, torch.Tensor) and isinstance(samples, torch.Tensor)
                    net.set_observation_statistics(demos, samples)
        self.rollouts = [*self.rollouts, steps][-self.config.pool_rollouts :]
        return steps

    def learn(self, policy: ActorCritic) -> dict[str, float]:
        """`discriminator_steps` minibatch steps on ℓ(D); their mean loss and accuracies."""
        self.discriminator.train()
        total = self.config.discriminator_steps
        statistics = [self._step(policy, step, total) for step in range(1, total + 1)]
        self.discriminator.train(False)
        self.learned += 1
        loss, demo_accuracy, sample_accuracy = np.mean(statistics, axis=0)
        self.last = {
            "discriminator_loss": float(loss),
            "demo_accuracy": float(demo_accuracy),
            "sample_accuracy": float(sample_accuracy),
        }
        return self.last

    def policy_rewards(self, steps: Steps, policy: ActorCritic) -> torch.Tensor:
        log_pi = (
            env_action_log_probs(policy, steps.observations, steps.env_actions) if self.discriminator.uses_policy else None
        )
        with torch.no_grad():
            return self.discriminator.policy_rewards(steps, log_pi)

    def _step(self, policy: ActorCritic, step: int, total: int) -> tuple[float, float, float]:
        size = self.config.batch_size
        demo_index = torch.randint(len(self.demos), (size,), generator=self.generator)
        batch = self.demos.select(demo_index).cat(self._negatives(size))
        log_pi = (
            env_action_log_probs(policy, batch.observations, batch.env_actions) if self.discriminator.uses_policy else None
        )
        penalised = self.config.gradient_penalty > 0
        logits, inputs = self.discriminator.logits(batch, log_pi, penalised=penalised)
        loss = discriminator_loss(logits[:size], logits[size:])
        if penalised:
            loss = loss + self.config.gradient_penalty * input_gradient_penalty(logits, inputs)
        if not torch.isfinite(loss):
            raise ImitationError(
                f"{self.config.method.upper()} discriminator round {self.learned + 1}, step {step}/{total}: the loss is "
                f"{loss.item()} (diverged; try a lower learning rate)"
            )
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.optimizer.step()
        return loss.item(), float((logits[:size] > 0).float().mean()), float((logits[size:] < 0).float().mean())

    def _negatives(self, size: int) -> Steps:
        """SIZE policy steps: round(ρ·SIZE) from the latest rollout, the rest from the whole pool."""
        latest = round(size * self.config.latest_share)
        parts = []
        if latest:
            newest = self.rollouts[-1]
            parts.append(newest.select(torch.randint(len(newest), (latest,), generator=self.generator)))
        if latest < size:
            pooled = sum(len(steps) for steps in self.rollouts)
            parts.append(self.pool_select(torch.randint(pooled, (size - latest,), generator=self.generator)))
        return parts[0].cat(*parts[1:])

    def pool_select(self, index: torch.Tensor) -> Steps:
        """The pool's steps at INDEX, counted through its rollouts oldest first; gathered from each
        rollout, so that a pool of many rollouts is not copied whole for every minibatch."""
        lengths = torch.tensor([len(steps) for steps in self.rollouts])
        ends = lengths.cumsum(0)
        rollout = torch.searchsorted(ends, index, right=True)
        offset = index - (ends - lengths)[rollout]
        parts, positions = [], []
        for k in rollout.unique().tolist():
            at = (rollout == k).nonzero().squeeze(1)
            parts.append(self.rollouts[k].select(offset[at]))
            positions.append(at)
        return parts[0].cat(*parts[1:]).select(torch.cat(positions).argsort())

    def state_dict(self) -> CheckpointData:
        checkpoint = CheckpointWriter(learned=self.learned, pooled=len(self.rollouts), last=self.last)
        checkpoint.module("discriminator", self.discriminator.state_dict())
        checkpoint.optimizer(self.optimizer)
        checkpoint.tensors["generator"] = self.generator.get_state()
        for k, steps in enumerate(self.rollouts):
            checkpoint.module(f"pool.{k}", flat_names(vars(steps)))
        return checkpoint.data()

    def load_state_dict(self, checkpoint: CheckpointData) -> None:
        """Continue from a `state_dict()` (KeyError, TypeError or RuntimeError when it is not one)."""
        tensors, state = checkpoint
        self.discriminator.load_state_dict(unprefixed("discriminator", tensors))
        restore_optimizer(self.optimizer, tensors, state["optimizer"], "optimizer")
        self.generator.set_state(tensors["generator"])
        self.rollouts = [Steps(**tree_of_names(unprefixed(f"pool.{k}", tensors))) for k in range(int(state["pooled"]))]
        self.learned = int(state["learned"])
        self.last = {str(name): float(value) for name, value in state["last"].items()}


class AdversarialImitation(BesidePPO[DiscriminatorLearner]):
    """The learner: PPO and the discriminator, one PPO update per step (the loop of the module
    docstring)."""

    def __init__(
        self,
        ppo: PPO,
        discriminator: Discriminator,
        demos: TransitionTensors,
        config: AdversarialConfig,
        *,
        fit_statistics: bool = True,
    ) -> None:
        super().__init__(ppo, DiscriminatorLearner(discriminator, demos, config, fit_statistics=fit_statistics))
        self.policy_updates = config.policy_updates

    @property
    def discriminator(self) -> DiscriminatorLearner:
        return self.side

    def step(self) -> dict[str, float]:
        rollout = self.ppo.collect_rollout()  # τ ~ π_k
        steps = self.discriminator.add_rollout(rollout)
        if self.ppo.updates % self.policy_updates == 0:
            self.discriminator.learn(self.ppo.policy)
        rewards = self.discriminator.policy_rewards(steps, self.ppo.policy)
        return self.ppo.update(rollout, rewards.reshape(rollout.env_rewards.shape)) | self.discriminator.last
