"""FlatAdam: the same steps as torch.optim.Adam with torch's global-norm clip, on one buffer,
and checkpoints that move between the two."""

from __future__ import annotations

import copy

import pytest
import torch
from torch import nn

from imitation.flat_adam import FlatAdam, clip_grad_norm


def _network(seed: int = 0) -> nn.Module:
    torch.manual_seed(seed)
    return nn.Sequential(nn.Linear(4, 16), nn.Tanh(), nn.Linear(16, 3))


def _train(network: nn.Module, optimizer: torch.optim.Optimizer | FlatAdam, steps: int, max_norm: float | None) -> None:
    generator = torch.Generator().manual_seed(1)
    for step in range(steps):
        inputs = torch.randn(32, 4, generator=generator)
        optimizer.param_groups[0]["lr"] = 1e-2 * (1 - step / (2 * steps))  # an annealed schedule, as PPO's
        optimizer.zero_grad(set_to_none=True)
        (network(inputs) ** 2).mean().mul(50.0).backward()
        if max_norm is not None:
            clip_grad_norm(optimizer, max_norm)
        optimizer.step()


@pytest.mark.parametrize("max_norm", [None, 0.5])
def test_steps_equal_torch_adam_with_torch_clipping(max_norm: float | None) -> None:
    ours, theirs = _network(), _network()
    _train(ours, FlatAdam(ours.parameters(), lr=1e-2, eps=1e-5), 40, max_norm)
    _train(theirs, torch.optim.Adam(theirs.parameters(), lr=1e-2, eps=1e-5), 40, max_norm)
    moved = [not torch.equal(a, b) for a, b in zip(ours.parameters(), _network().parameters())]
    assert all(moved)
    for mine, reference in zip(ours.parameters(), theirs.parameters()):
        torch.testing.assert_close(mine, reference, rtol=0, atol=1e-6)


def test_the_clip_bounds_the_global_norm_and_leaves_small_gradients() -> None:
    network = _network()
    optimizer = FlatAdam(network.parameters())
    network(torch.randn(8, 4)).sum().mul(100.0).backward()
    norm = torch.linalg.vector_norm(torch.cat([p.grad.reshape(-1) for p in network.parameters()]))
    assert norm > 1.0
    optimizer.clip_grad_norm_(1.0)
    assert torch.linalg.vector_norm(optimizer.grad).item() == pytest.approx(1.0, rel=1e-5)
    before = optimizer.grad.clone()
    optimizer.clip_grad_norm_(10.0)
    assert torch.equal(optimizer.grad, before)


def test_parameters_and_gradients_are_views_of_the_flat_buffers() -> None:
    network = _network()
    optimizer = FlatAdam(network.parameters())
    network(torch.randn(8, 4)).sum().backward()
    assert torch.equal(optimizer.grad, torch.cat([p.grad.reshape(-1) for p in network.parameters()]))
    network.zero_grad(set_to_none=True)  # drops the views: the next backward's gradients are gathered back
    network(torch.randn(8, 4)).sum().backward()
    expected = torch.cat([p.grad.reshape(-1) for p in network.parameters()])
    before = optimizer.flat.clone()
    optimizer.step()
    assert torch.equal(optimizer.grad, expected)
    assert torch.equal(optimizer.flat, torch.cat([p.detach().reshape(-1) for p in network.parameters()]))
    assert not torch.equal(optimizer.flat, before)


def test_a_state_moves_to_torch_adam_and_back_and_training_continues_identically() -> None:
    ours, theirs = _network(), _network()
    flat, adam = FlatAdam(ours.parameters(), lr=1e-2), torch.optim.Adam(theirs.parameters(), lr=1e-2)
    _train(ours, flat, 5, None)
    _train(theirs, adam, 5, None)
    moved_to_torch, moved_to_flat = copy.deepcopy(theirs), copy.deepcopy(ours)
    torch_from_flat = torch.optim.Adam(moved_to_torch.parameters())
    torch_from_flat.load_state_dict(copy.deepcopy(flat.state_dict()))  # its tensors are the live moments
    flat_from_torch = FlatAdam(moved_to_flat.parameters())
    flat_from_torch.load_state_dict(copy.deepcopy(adam.state_dict()))
    assert flat_from_torch.steps == 5 and torch_from_flat.state_dict()["state"][0]["step"].item() == 5.0
    assert flat_from_torch.param_groups[0]["lr"] == adam.param_groups[0]["lr"]
    _train(ours, flat, 5, None)
    for network, optimizer in ((moved_to_torch, torch_from_flat), (moved_to_flat, flat_from_torch)):
        _train(network, optimizer, 5, None)
        for mine, reference in zip(network.parameters(), ours.parameters()):
            torch.testing.assert_close(mine, reference, rtol=0, atol=1e-6)


def test_a_state_of_another_model_is_refused() -> None:
    small, large = FlatAdam(_network().parameters()), FlatAdam(nn.Linear(4, 3).parameters())
    with pytest.raises(ValueError, match="2 parameters, this model 4"):
        small.load_state_dict(large.state_dict())
