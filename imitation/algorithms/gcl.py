"""Sample-based maximum-entropy IRL for continuous states: guided cost learning (Finn et al. 2016;
docs/THEORY.md §8).

The MaxEnt model of docs/THEORY.md §7 is kept, p_θ(τ) ∝ p(τ | dynamics) exp R_θ(τ), but the partition
function Z = Σ_τ exp R_θ(τ) can no longer be summed over a tabular MDP. It is estimated from
samples of a density q, drawn by the policies π_k that PPO keeps close to the soft-optimal
policy of the current reward, with importance weights exp R_θ(τ) / q(τ) (the dynamics cancel):

    L(θ) = -E_demo[R_θ(τ)] + log E_{τ ~ q}[exp R_θ(τ) / q(τ)]

Following Finn, Christiano, Abbeel & Levine (2016, "A connection between GANs, IRL and
energy-based models"), q is one density for every point, the mixture of all the samplers so far,

    q(a|s) = (1/K) Σ_{k=1}^{K} π_k(a|s)     (π_1 … π_K: the policies whose rollouts are pooled),

per step (trajectories of one step, which keeps the weights' variance bounded, the samplers'
state distributions taken as common so that, like the dynamics, they cancel), and the importance
sampling runs on μ = ½ p̂ + ½ q of demos and pooled samples, with the current model
p̂(a|s) = exp r_θ(s) / Z standing in for the demos' density. The gradient of L(θ) is then the
gradient of the logistic loss of the discriminator

    D_θ(s, a) = exp r_θ(s) / (exp r_θ(s) + Z q(a|s)),   logit D_θ = r_θ(s) - log Z - log q(a|s),

trained to tell demo steps (label 1) from pooled steps (label 0), log Z a parameter of its own
(`objective="discriminator"`, the default). `objective="importance"` minimises the
self-normalised estimate of L(θ) itself over B = demos ∪ samples, |B| = 2N,

    -mean_demo r + log (1/2N) Σ_{j ∈ B} exp r_j / μ_j,    μ_j = ½ exp(r_j - log Z) + ½ q_j,

with log Z in μ the previous step's estimate, log (1/2N) Σ_j exp r_j / μ_j.

The model holds only if π_k is the soft-optimal policy of r_θ, so PPO alongside optimises the
maximum-entropy objective, the reward r_θ(s) - α log π_k(a|s) with α = 1 (`policy_entropy`),
AIRL's log D_θ - log(1 - D_θ) with q = π_k, up to log Z (Fu et al. 2018). With PPO on r_θ alone,
its policy grew sharper than the (near-deterministic) demos' actions allow, D_θ told them apart
by log π_k alone, and r_θ stayed flat (bench/RESULTS.md).
Box actions are clipped to the bounds, so log π_k is that of the clipped (censored) Gaussian,
demos and samples alike (`ActorCritic.env_action_log_prob`): a demo's full torque is then as
likely to the policy as its own saturated actions.

The outer loop (`GuidedCostLearning.step`), once per PPO update:

    τ ← rollout of π_k                                     (PPO.collect_rollout)
    (1) pool ← pool ∪ τ;  q ← the mixture with π_k         (RewardLearner.add_rollout)
    (2) `reward_steps` minibatch steps on the loss, then    (RewardLearner.learn)
        r_θ shifted to mean 0 over the demos (log Z with it)
    (3) PPO update on r_θ(s) - α log π_k(a|s) over τ       (PPO.update)

The pool keeps every rollout, so states the policy has stopped visiting stay rated; log Σ_k
π_k(a|s) is brought up to date for every pooled and demo step by one pass of π_k over the old
steps and of π_1 … π_k over the new ones. The first rollout takes `warmup_steps` more reward
steps, and the reward's learning rate is annealed to 0 so that PPO ends on a settled reward. A
gradient penalty on r_θ's inputs keeps it smooth. The recovered r_θ is what `train ppo --reward`
later optimises from scratch; the policy trained alongside is the soft-optimal one,
deliberately random, and is not meant for use.

The state saved with PPO's is r_θ, log Z, their Adam state, the pool, the samplers π_1 … π_K
and the minibatch generator's position, so an interrupted run resumes exactly.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import cast

import numpy as np
import torch
from torch import nn

from imitation.algorithms.beside_ppo import BesidePPO, env_action_log_probs
from imitation.algorithms.gcl_config import GCLConfig
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
from imitation.policies import ActorCritic, PolicyConfig
from imitation.rewards import RewardNet, flat_batch, tree_index
from imitation.tensors import TensorTree, tree_cat


@dataclass
class _Samples:
    observations: TensorTree
    env_actions: torch.Tensor
    next_observations: TensorTree
    # log Σ_k π_k(a|s) over the samplers so far (log q + log K).
    log_mass: torch.Tensor


class RewardLearner:
    """The reward side of GCL: r_θ and log Z, the pool of samples with the mixture q of their
    samplers, and the minibatch steps on the loss."""

    def __init__(self, reward: RewardNet, demos: TransitionTensors, config: GCLConfig, *, updates: int) -> None:
        config.validate()
        if demos.next_observations is None:
            raise ImitationError("GCL's demos need next observations (load them with next_observations=True)")
        self.reward = reward
        self.demos = demos
        self.config = config
        self.updates = updates  # of PPO, over which the learning rate is annealed
        # log Z, the discriminator's offset, kept apart from r_θ so that centring r_θ on the demos
        # leaves the classifier where its loss put it.
        self.log_partition = nn.Parameter(torch.zeros(()))
        self.optimizer = torch.optim.Adam([*reward.parameters(), self.log_partition], lr=config.learning_rate)
        self.pool: _Samples | None = None
        # π_1 … π_K, CPU copies of the policy as it was at each pooled rollout.
        self.samplers: list[ActorCritic] = []
        self.demo_log_mass = torch.full((len(demos),), -float("inf"))
        self.generator = torch.Generator().manual_seed(config.seed)
        self.learned = 0  # reward updates so far, one per pooled rollout

    def add_rollout(self, rollout: Rollout, policy: ActorCritic) -> torch.Tensor:
        """Pool the rollout's steps and add its sampler π_k to the mixture; log π_k(a|s) of its
        steps, shaped as the rollout, on the CPU."""
        rollout = rollout.cpu_copy()
        if self.reward.config.normalize_observations and self.pool is None:
            # Where the space is unbounded, the first policy's states widen the demos' spread.
            demo_observations = self._demo_steps()[0]
            assert isinstance(demo_observations, torch.Tensor)  # statistics are of Box observations (RewardNet)
            self.reward.set_observation_statistics(demo_observations, flat_batch(rollout.observations, 2))
        observations, env_actions = flat_batch(rollout.observations, 2), flat_batch(rollout.env_actions, 2)
        sampler = copy.deepcopy(policy).to("cpu").eval()
        own_log_probs = env_action_log_probs(sampler, observations, env_actions)
        earlier = [env_action_log_probs(old, observations, env_actions) for old in self.samplers]
        new = _Samples(
            observations=observations,
            env_actions=env_actions,
            next_observations=flat_batch(rollout.next_observations, 2),
            log_mass=torch.logsumexp(torch.stack([own_log_probs, *earlier]), 0),
        )
        demo_observations, demo_actions, _ = self._demo_steps()
        self.demo_log_mass = torch.logaddexp(
            self.demo_log_mass, env_action_log_probs(sampler, demo_observations, demo_actions)
        )
        if self.pool is None:
            self.pool = new
        else:
            self.pool.log_mass = torch.logaddexp(
                self.pool.log_mass, env_action_log_probs(sampler, self.pool.observations, self.pool.env_actions)
            )
            self.pool = _Samples(
                **{name: tree_cat(getattr(self.pool, name), getattr(new, name)) for name in _Samples.__dataclass_fields__}
            )
        self.samplers.append(sampler)
        return own_log_probs.reshape(rollout.env_rewards.shape)

    def learn(self) -> dict[str, float]:
        """`reward_steps` minibatch steps on the loss (`warmup_steps` more the first time), then
        r_θ centred on the demos; the steps' mean loss and accuracies."""
        self.reward.train()
        if self.config.anneal_lr:
            self.optimizer.param_groups[0]["lr"] = self.config.learning_rate * max(0.0, 1.0 - self.learned / self.updates)
        steps = self.config.reward_steps + (self.config.warmup_steps if self.learned == 0 else 0)
        statistics = [self._step(step, steps) for step in range(1, steps + 1)]
        self.reward.eval()
        self._center_on_demos()
        self.learned += 1
        loss, demo_accuracy, sample_accuracy = np.mean(statistics, axis=0)
        return {"reward_loss": float(loss), "demo_accuracy": float(demo_accuracy), "sample_accuracy": float(sample_accuracy)}

    def state_dict(self) -> CheckpointData:
        """Everything to go on as if never stopped (live tensors: the loop copies them)."""
        samplers = self.samplers[0].config.to_json() if self.samplers else None
        checkpoint = CheckpointWriter(learned=self.learned, samplers=len(self.samplers), sampler_policy=samplers)
        checkpoint.module("reward", self.reward.state_dict())
        checkpoint.optimizer(self.optimizer)
        checkpoint.tensors |= {
            "generator": self.generator.get_state(),
            "log_partition": self.log_partition.detach(),
            "demo_log_mass": self.demo_log_mass,
        }
        if self.pool is not None:
            checkpoint.module("pool", flat_names(vars(self.pool)))
        for k, sampler in enumerate(self.samplers):
            checkpoint.module(f"sampler.{k}", sampler.state_dict())
        return checkpoint.data()

    def load_state_dict(self, checkpoint: CheckpointData) -> None:
        """Continue from a `state_dict()` (KeyError or RuntimeError when it is not one)."""
        tensors, state = checkpoint
        self.reward.load_state_dict(unprefixed("reward", tensors))
        with torch.no_grad():
            self.log_partition.copy_(tensors["log_partition"])
        restore_optimizer(self.optimizer, tensors, state["optimizer"], "optimizer")
        self.generator.set_state(tensors["generator"])
        self.demo_log_mass = tensors["demo_log_mass"].clone()
        pool = unprefixed("pool", tensors)
        self.pool = _Samples(**tree_of_names(pool)) if pool else None
        self.samplers = []
        for k in range(int(state["samplers"])):
            sampler = ActorCritic(PolicyConfig.from_json(state["sampler_policy"]))
            sampler.load_state_dict(unprefixed(f"sampler.{k}", tensors))
            self.samplers.append(sampler.eval())
        self.learned = int(state["learned"])

    def _step(self, step: int, steps: int) -> tuple[float, float, float]:
        size = self.config.batch_size
        demo_index = torch.randint(len(self.demos), (size,), generator=self.generator)
        samples = self._sample_batch(size)
        demo_observations, demo_actions, demo_next_observations = self._demo_steps()
        inputs = [
            part.requires_grad_(self.config.gradient_penalty > 0)
            for part in self.reward.prepare(
                tree_cat(tree_index(demo_observations, demo_index), samples.observations),
                torch.cat([demo_actions[demo_index], samples.env_actions]),
                tree_cat(tree_index(demo_next_observations, demo_index), samples.next_observations),
            )
        ]
        rewards = self.reward.score(inputs)
        log_q = torch.cat([self.demo_log_mass[demo_index], samples.log_mass]) - np.log(len(self.samplers))
        logits = rewards - self.log_partition - log_q
        demo_logits, sample_logits = logits[:size], logits[size:]
        if self.config.objective == "importance":
            loss = -rewards[:size].mean() + self._log_partition_estimate(rewards, log_q)
        else:
            labels = torch.cat([torch.ones(size), torch.zeros(size)])
            loss = nn.functional.binary_cross_entropy_with_logits(logits, labels)
        if self.config.gradient_penalty > 0:
            # A smooth reward ranks states by how near they come to the demos' states, which is
            # what lets PPO find them from scratch; a sharp one is flat everywhere else. An image
            # reward is smoothed in its pixels, not in its CNN's features, which could grow to
            # escape the penalty.
            gradients = torch.autograd.grad(rewards.sum(), inputs, create_graph=True)
            squared = sum(gradient.pow(2).reshape(len(gradient), -1).sum(-1) for gradient in gradients)
            loss = loss + self.config.gradient_penalty * cast(torch.Tensor, squared).mean()
        if not torch.isfinite(loss):
            raise ImitationError(
                f"GCL reward update {self.learned + 1}, step {step}/{steps}: the loss is {loss.item()} (diverged; try a "
                "lower learning rate)"
            )
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.optimizer.step()
        return loss.item(), float((demo_logits > 0).float().mean()), float((sample_logits < 0).float().mean())

    def _log_partition_estimate(self, rewards: torch.Tensor, log_q: torch.Tensor) -> torch.Tensor:
        """log Ẑ = log (1/|B|) Σ_{j ∈ B} exp r_j / μ_j over demos and samples, μ = ½ p̂ + ½ q with
        p̂ = exp(r - log Z) at the previous estimate of log Z, which this one then replaces."""
        log_mu = torch.logaddexp(rewards.detach() - self.log_partition.detach(), log_q) - np.log(2.0)
        estimate = torch.logsumexp(rewards - log_mu, 0) - np.log(len(rewards))
        with torch.no_grad():
            self.log_partition.copy_(estimate)
        return estimate

    def _center_on_demos(self) -> None:
        """Shift r_θ so that its mean over the demos' steps is 0: the constant is arbitrary (log Z
        is absorbed into it), and PPO's critic learns far faster when the expert's behaviour is
        worth about 0 and everything else costs, than when every value sits at some large
        offset (bench/RESULTS.md)."""
        with torch.no_grad():
            offset = self.reward.rewards_of(*self._demo_steps()).mean()
            last = self.reward.net[-1]
            assert isinstance(last, nn.Linear)
            last.bias.sub_(offset)
            self.log_partition.sub_(offset)  # in place, as `-=` did (without re-registering the parameter)

    def _demo_steps(self) -> tuple[TensorTree, torch.Tensor, TensorTree]:
        """The demos' s, a and s' (s and s' dicts of tensors for Dict observations; a reward model
        takes no Dict actions; s' is checked present in __init__)."""
        demos = self.demos
        assert isinstance(demos.actions, torch.Tensor) and demos.next_observations is not None
        return demos.observations, demos.actions, demos.next_observations

    def _sample_batch(self, size: int) -> _Samples:
        """`size` pooled steps drawn uniformly."""
        assert self.pool is not None
        index = torch.randint(len(self.pool.log_mass), (size,), generator=self.generator)
        return _Samples(**{name: tree_index(getattr(self.pool, name), index) for name in _Samples.__dataclass_fields__})


class GuidedCostLearning(BesidePPO[RewardLearner]):
    """The learner: PPO and the reward learner, one PPO update per step (the outer loop of the
    module docstring)."""

    def __init__(self, ppo: PPO, reward: RewardNet, demos: TransitionTensors, config: GCLConfig) -> None:
        super().__init__(ppo, RewardLearner(reward, demos, config, updates=ppo.total))
        self.policy_entropy = config.policy_entropy

    @property
    def rewards(self) -> RewardLearner:
        return self.side

    def step(self) -> dict[str, float]:
        rollout = self.ppo.collect_rollout()  # τ ~ π_k
        log_pi = self.rewards.add_rollout(rollout, self.ppo.policy)  # (1)
        statistics = self.rewards.learn()  # (2)
        optimised = self.rewards.reward.relabel(rollout) - self.policy_entropy * log_pi.to(rollout.env_rewards.device)
        return self.ppo.update(rollout, optimised) | statistics  # (3)
