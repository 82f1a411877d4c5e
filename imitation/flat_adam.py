"""Adam over one flat buffer: the parameters, their gradients and both moments are each one
contiguous tensor, and every parameter is a view into it.

For θ with gradient g at step t (Kingma & Ba 2015, as torch.optim.Adam computes it):

    m_t = β₁ m_{t-1} + (1 - β₁) g
    v_t = β₂ v_{t-1} + (1 - β₂) g²
    θ_t = θ_{t-1} - lr · (m_t / (1 - β₁ᵗ)) / (√(v_t / (1 - β₂ᵗ)) + ε)

and the global-norm clip g ← g · min(1, c / (‖g‖₂ + 10⁻⁶)) of `torch.nn.utils.clip_grad_norm_`.
A parameter that gets no gradient is stepped with g = 0, where torch.optim.Adam skips it; the
two agree while its moments are zero, as for a part of the model that the loss never reads.

Why flat: the small networks of PPO and BC have a dozen parameter tensors of a few thousand
numbers each, so torch.optim.Adam on the CPU spends its time in per-tensor dispatch, not
arithmetic. On one buffer each line above is one kernel. It also keeps torch.optim out of the
process: its first optimiser imports torch._dynamo, about a second of every cold start.

The state dict has torch.optim.Adam's layout (per-parameter step, exp_avg, exp_avg_sq; one
parameter group), so checkpoints move between the two."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np
import torch
from torch import nn


class FlatAdam:
    """Adam (no weight decay) on `parameters`, which it re-points into one flat buffer; the
    parameter group's "lr" may be changed between steps, as with torch.optim."""

    def __init__(
        self,
        parameters: Iterable[nn.Parameter],
        lr: float = 1e-3,
        betas: tuple[float, float] = (0.9, 0.999),
        eps: float = 1e-8,
    ) -> None:
        self.parameters = [parameter for parameter in parameters if parameter.requires_grad]
        if not self.parameters:
            raise ValueError("FlatAdam got no parameters that require gradients")
        first = self.parameters[0]
        if any(p.device != first.device or p.dtype != first.dtype for p in self.parameters):
            raise ValueError("FlatAdam's parameters must share one device and dtype")
        self.flat = torch.cat([p.detach().reshape(-1) for p in self.parameters])
        self.grad = torch.zeros_like(self.flat)
        self.exp_avg = torch.zeros_like(self.flat)
        self.exp_avg_sq = torch.zeros_like(self.flat)
        self._denominator = torch.empty_like(self.flat)
        self.slices: list[slice] = []
        offset = 0
        for parameter in self.parameters:
            size = parameter.numel()
            self.slices.append(slice(offset, offset + size))
            parameter.data = self.flat[offset : offset + size].view_as(parameter)
            offset += size
        self.steps = 0
        self.defaults: dict[str, Any] = {"lr": lr, "betas": betas, "eps": eps, "weight_decay": 0.0}
        self.param_groups: list[dict[str, Any]] = [{"params": self.parameters, **self.defaults}]
        self._grad_views = [self._view(self.grad, index) for index in range(len(self.parameters))]
        self._grad_addresses = [view.data_ptr() for view in self._grad_views]
        self._link_gradients()

    def _view(self, buffer: torch.Tensor, index: int) -> torch.Tensor:
        return buffer[self.slices[index]].view_as(self.parameters[index])

    def _link_gradients(self) -> None:
        for parameter, view in zip(self.parameters, self._grad_views):
            parameter.grad = view

    def _gather_gradients(self) -> None:
        """Gradients back into the flat buffer where someone replaced or dropped a view (e.g.
        nn.Module.zero_grad, which sets them to None); backward accumulates into the views."""
        for parameter, view, address in zip(self.parameters, self._grad_views, self._grad_addresses):
            grad = parameter.grad
            if grad is None:
                view.zero_()
            elif grad.data_ptr() != address:
                view.copy_(grad)
            else:
                continue
            parameter.grad = view

    def flat_gradient(self) -> torch.Tensor:
        """g as the one flat tensor the step reads (changed in place, the step sees the change)."""
        self._gather_gradients()
        return self.grad

    def zero_grad(self, set_to_none: bool = True) -> None:
        """Zero the flat gradient (the views stay in place whatever `set_to_none` says)."""
        del set_to_none
        self.grad.zero_()
        self._link_gradients()

    def clip_grad_norm_(self, max_norm: float) -> None:
        """Scale g to global norm at most `max_norm`."""
        self._gather_gradients()
        self.grad.mul_(torch.clamp(max_norm / (torch.linalg.vector_norm(self.grad) + 1e-6), max=1.0))

    @torch.no_grad()
    def step(self) -> None:
        self._gather_gradients()
        group = self.param_groups[0]
        beta1, beta2 = group["betas"]
        self.steps += 1
        self.exp_avg.lerp_(self.grad, 1 - beta1)
        self.exp_avg_sq.mul_(beta2).addcmul_(self.grad, self.grad, value=1 - beta2)
        step_size = group["lr"] / (1 - beta1**self.steps)
        denominator = self._denominator
        if denominator.device.type == "cpu":
            # numpy's: torch's vectorised CPU sqrt is many times slower on zeros (bench/ppo_step.py),
            # which the moments of parameters without gradients (BC's unused critic) are.
            np.sqrt(self.exp_avg_sq.numpy(), out=denominator.numpy())
        else:
            torch.sqrt(self.exp_avg_sq, out=denominator)
        denominator.div_((1 - beta2**self.steps) ** 0.5).add_(group["eps"])
        self.flat.addcdiv_(self.exp_avg, denominator, value=-step_size)

    def _state(self, index: int) -> dict[str, torch.Tensor]:
        return {
            "step": torch.tensor(float(self.steps)),
            "exp_avg": self._view(self.exp_avg, index),
            "exp_avg_sq": self._view(self.exp_avg_sq, index),
        }

    @property
    def state(self) -> dict[nn.Parameter, dict[str, torch.Tensor]]:
        """Per parameter, as torch.optim's `state` (empty before the first step)."""
        return {parameter: self._state(index) for index, parameter in enumerate(self.parameters)} if self.steps else {}

    def state_dict(self) -> dict[str, Any]:
        """torch.optim.Adam's layout; the moments are views of the live buffers."""
        state = {index: self._state(index) for index in range(len(self.parameters))} if self.steps else {}
        group = {key: value for key, value in self.param_groups[0].items() if key != "params"}
        group.update(amsgrad=False, maximize=False, foreach=None, capturable=False, differentiable=False, fused=None)
        return {"state": state, "param_groups": [group | {"params": list(range(len(self.parameters)))}]}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        """A state of this optimiser or of torch.optim.Adam over the same parameters."""
        (group,) = state_dict["param_groups"]
        if len(group["params"]) != len(self.parameters):
            raise ValueError(f"the optimiser state has {len(group['params'])} parameters, this model {len(self.parameters)}")
        state = state_dict["state"]
        steps = {int(values["step"]) for values in state.values()}
        if len(steps) > 1:
            raise ValueError(f"the optimiser state's parameters are at different steps {sorted(steps)}")
        with torch.no_grad():
            for index, position in enumerate(group["params"]):
                values = state.get(position)
                for name, buffer in (("exp_avg", self.exp_avg), ("exp_avg_sq", self.exp_avg_sq)):
                    if values is None:
                        self._view(buffer, index).zero_()
                    else:
                        self._view(buffer, index).copy_(values[name])
        self.steps = steps.pop() if steps else 0
        self.param_groups[0].update(lr=float(group["lr"]), betas=tuple(group["betas"]), eps=float(group["eps"]))


def clip_grad_norm(optimizer: torch.optim.Optimizer | FlatAdam, max_norm: float) -> None:
    """The global-norm clip of the gradients of `optimizer`'s parameters: one kernel on a
    FlatAdam's buffer, torch's per-tensor clip on another optimiser's."""
    if isinstance(optimizer, FlatAdam):
        optimizer.clip_grad_norm_(max_norm)
    else:
        parameters = [parameter for group in optimizer.param_groups for parameter in group["params"]]
        torch.nn.utils.clip_grad_norm_(parameters, max_norm, foreach=True)
