"""Benchmark: one PPO gradient step of the CartPole zoo settings, three ways, and what compiling costs.

The step of `ppo_update` at bench/ppo.py's CartPole size (two 64-64 tanh MLPs, a minibatch of 256,
the clipped surrogate plus the value loss, the global-norm clip at 0.5, Adam at eps 1e-5), with
- torch.optim.Adam and torch.nn.utils.clip_grad_norm_ (the floor bench/ppo.py's update row uses);
- imitation's FlatAdam (what `PPO` runs);
- the loss compiled by torch.compile (inductor), FlatAdam after it: the first call's cost, then per step.
Also torch's CPU sqrt on zeros against random values (FlatAdam takes its square root through numpy).
One torch thread; median of --repeats timings of --steps steps each.

Usage: python bench/ppo_step.py [--steps 2000] [--repeats 3] [--no-compile]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import torch
from torch import nn

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from imitation.flat_adam import FlatAdam, clip_grad_norm  # noqa: E402

BATCH = 256


def _mlp(outputs: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(4, 64), nn.Tanh(), nn.Linear(64, 64), nn.Tanh(), nn.Linear(64, outputs))


def _loss(actor: nn.Module, critic: nn.Module, batch: tuple[torch.Tensor, ...]) -> torch.Tensor:
    observations, actions, old_log_probs, advantages, returns = batch
    log_probs = torch.log_softmax(actor(observations), -1).gather(1, actions[:, None]).squeeze(1)
    ratio = (log_probs - old_log_probs).exp()
    advantages = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
    policy_loss = -torch.min(ratio * advantages, ratio.clamp(0.8, 1.2) * advantages).mean()
    return policy_loss + 0.5 * 0.5 * ((critic(observations).squeeze(-1) - returns) ** 2).mean()


def _stepper(kind: str) -> Callable[[], None]:
    torch.manual_seed(0)
    actor, critic = _mlp(2), _mlp(1)
    parameters = [*actor.parameters(), *critic.parameters()]
    batch = (
        torch.randn(BATCH, 4),
        torch.randint(0, 2, (BATCH,)),
        torch.randn(BATCH) * 0.1 - 0.7,
        torch.randn(BATCH),
        torch.randn(BATCH),
    )
    optimizer: torch.optim.Optimizer | FlatAdam
    optimizer = (
        torch.optim.Adam(parameters, lr=1e-3, eps=1e-5)
        if kind == "torch.optim.Adam"
        else FlatAdam(parameters, lr=1e-3, eps=1e-5)
    )
    loss = torch.compile(_loss) if kind == "compiled + FlatAdam" else _loss

    def step() -> None:
        value = loss(actor, critic, batch)
        optimizer.zero_grad(set_to_none=True)
        value.backward()
        clip_grad_norm(optimizer, 0.5)
        optimizer.step()

    return step


def _per_call(function: Callable[[], object], calls: int, repeats: int) -> float:
    timings = []
    for _ in range(repeats):
        started = time.perf_counter()
        for _ in range(calls):
            function()
        timings.append((time.perf_counter() - started) / calls)
    return statistics.median(timings)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--no-compile", action="store_true", help="skip the compiled row (its first call takes ~30 s)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    kinds = ["torch.optim.Adam", "FlatAdam"] + ([] if args.no_compile else ["compiled + FlatAdam"])
    print(f"one gradient step, batch {BATCH}, one torch thread, median of {args.repeats} × {args.steps} steps:")
    for kind in kinds:
        step = _stepper(kind)
        started = time.perf_counter()
        step()
        first = time.perf_counter() - started
        for _ in range(100):
            step()
        print(f"  {kind:22s} first call {first:8.3f} s   then {_per_call(step, args.steps, args.repeats) * 1e6:7.1f} µs/step")
    zeros, uniform = torch.zeros(135_000), torch.rand(135_000)
    print("torch's CPU sqrt of 135,000 floats:")
    for name, values in (("zeros", zeros), ("uniform [0, 1)", uniform)):
        print(f"  {name:16s} {_per_call(values.sqrt, 200, args.repeats) * 1e6:7.1f} µs")


if __name__ == "__main__":
    main()
