"""What the learners that run beside PPO share (guided cost learning's reward learner, GAIL's and
AIRL's discriminator): the loop's bookkeeping with PPO's checkpoint (`BesidePPO`), and the policy's
log π(a|s) of env actions, which GCL's importance weights and AIRL's discriminator read."""

from __future__ import annotations

from typing import Protocol

import torch

from imitation.algorithms.ppo import PPO
from imitation.checkpoints import CheckpointData, CheckpointReader, prefixed
from imitation.policies import ActorCritic
from imitation.rewards import tree_index
from imitation.tensors import TensorTree

# Steps per forward pass when a sampler scores the pool: bounds the activations' memory.
_CHUNK = 65_536


def env_action_log_probs(policy: ActorCritic, observations: TensorTree, env_actions: torch.Tensor) -> torch.Tensor:
    """log π(a|s) of env actions (clipped ones as the mass at the bound, on the same footing for
    demos and samples: `ActorCritic.env_action_log_prob`), computed where the policy is, returned on the CPU."""
    with torch.no_grad():
        device = policy.action_head.weight.device
        parts = []
        for start in range(0, len(env_actions), _CHUNK):
            chunk = slice(start, start + _CHUNK)
            distribution = policy.distribution(policy.encode(tree_index(observations, chunk, device)))
            parts.append(policy.env_action_log_prob(distribution, env_actions[chunk].to(device)).cpu())
        return torch.cat(parts)


class Checkpointed(Protocol):
    def state_dict(self) -> CheckpointData: ...

    def load_state_dict(self, checkpoint: CheckpointData) -> None: ...


class BesidePPO[Side: Checkpointed]:
    """A learner that runs beside PPO, one PPO update per step (GCL's reward learner, GAIL's and
    AIRL's discriminator): PPO's steps, progress and interruption messages, and PPO's checkpoint
    with the other side's state under "learner"."""

    name = PPO.name  # its steps are PPO's updates, and an interruption is reported as PPO's
    unit = PPO.unit

    def __init__(self, ppo: PPO, side: Side) -> None:
        self.ppo = ppo
        self.side = side
        self.total = ppo.total

    @property
    def completed(self) -> int:
        return self.ppo.completed

    @property
    def done(self) -> bool:
        return self.ppo.done

    def position(self) -> str:
        return self.ppo.position()

    def progress(self, row: dict[str, float]) -> dict[str, str]:
        return self.ppo.progress(row) | {"demo_acc": f"{row['demo_accuracy']:.2f}"}

    def state_dict(self) -> CheckpointData:
        tensors, state = self.ppo.state_dict()
        side_tensors, state["learner"] = self.side.state_dict()
        return tensors | prefixed("learner", side_tensors), state

    def load_state_dict(self, checkpoint: CheckpointData) -> None:
        self.ppo.load_state_dict(checkpoint)
        with CheckpointReader(checkpoint, "PPO") as saved:
            self.side.load_state_dict((saved.module("learner"), saved.state["learner"]))
