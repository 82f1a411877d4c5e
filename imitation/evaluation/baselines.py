"""Trivial baselines beside a behavioural-cloning result, scored on the same held-out transitions:
what a cloned policy must beat before its loss means anything.

- constant: one action distribution for every state, fitted to the training actions (a
  Gaussian with their per-dimension mean and std; for discrete actions their class frequencies);
- hold: the episode's previous action, for actions that are a command stream held between
  changes (a teleoperator's key, a velocity command); the Gaussian around it has the training
  set's residual std per dimension; the first step of an episode falls back to `constant`;
- copy_state: the current observation as the action, where the two have one shape and so may
  share units (joint targets beside joint positions), with the training residuals' std.

Each is scored as the policy is: the mean negative log-likelihood of the held-out actions and the
mean squared error of its point prediction (summed over action dimensions); for discrete actions
the error rate instead of the squared error. Hold and copy-state score Box actions only.
"""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import torch

from imitation.data.loader import TransitionTensors
from imitation.envs.previous_action import previous_actions
from imitation.policy_protocol import ImitationPolicy

Scores = dict[str, float]
# A floor on fitted standard deviations: a dimension that never moves in the training data would
# otherwise make any held-out change infinitely unlikely.
MIN_STD = 1e-3


def _gaussian_nll(residuals: np.ndarray, std: np.ndarray) -> float:
    return float((0.5 * (residuals / std) ** 2 + np.log(std) + 0.5 * math.log(2 * math.pi)).sum(-1).mean())


def _box_scores(predictions: np.ndarray, actions: np.ndarray, std: np.ndarray) -> Scores:
    residuals = actions - predictions
    return {"nll": _gaussian_nll(residuals, std), "mse": float((residuals**2).sum(-1).mean())}


def _rows(tensor: torch.Tensor) -> np.ndarray:
    return tensor.cpu().numpy().reshape(len(tensor), -1).astype(np.float64)


def baseline_scores(train: TransitionTensors, validation: TransitionTensors, action_space: gym.Space) -> dict[str, Scores]:
    """The baselines that apply to this data, each scored on `validation` (see the module docstring)."""
    # Arrays, not dicts: behavioural cloning refuses Dict action spaces before it gets here.
    assert isinstance(train.actions, torch.Tensor) and isinstance(validation.actions, torch.Tensor)
    if isinstance(action_space, gym.spaces.Discrete):
        counts = np.bincount(train.actions.cpu().numpy().reshape(-1) - int(action_space.start), minlength=int(action_space.n))
        frequencies = (counts + 1) / (counts.sum() + len(counts))  # add-one: a class unseen in training is not impossible
        held = validation.actions.cpu().numpy().reshape(-1) - int(action_space.start)
        return {
            "constant": {
                "nll": float(-np.log(frequencies[held]).mean()),
                "error_rate": float((held != frequencies.argmax()).mean()),
            }
        }
    if not isinstance(action_space, gym.spaces.Box):
        return {}
    train_actions, held = _rows(train.actions), _rows(validation.actions)
    mean, std = train_actions.mean(0), np.maximum(train_actions.std(0), MIN_STD)
    scores = {"constant": _box_scores(np.broadcast_to(mean, held.shape), held, std)}
    train_episodes, held_episodes = train.episode_index.cpu().numpy(), validation.episode_index.cpu().numpy()
    train_previous, _ = previous_actions(train_actions, train_episodes, mean)
    hold_std = np.maximum((train_actions - train_previous).std(0), MIN_STD)
    scores["hold"] = _box_scores(previous_actions(held, held_episodes, mean)[0], held, hold_std)
    if isinstance(train.observations, torch.Tensor) and isinstance(validation.observations, torch.Tensor):
        train_states, held_states = _rows(train.observations), _rows(validation.observations)
        if train_states.shape[1] == train_actions.shape[1]:
            copy_std = np.maximum((train_actions - train_states).std(0), MIN_STD)
            scores["copy_state"] = _box_scores(held_states, held, copy_std)
    return scores


def policy_scores(policy: ImitationPolicy, validation: TransitionTensors, *, rows: int = 1024) -> Scores:
    """The policy on `validation`, scored as the baselines are: its NLL of the held-out actions
    (for a kind with a likelihood), and the squared error of its point action (Box) or the error
    rate of its most likely action (Discrete). Batches of `rows` bound the memory a CNN's
    activations take."""
    totals: dict[str, float] = {}
    for start in range(0, len(validation), rows):
        piece = validation.select(torch.arange(start, min(start + rows, len(validation)), device=validation.device))
        for name, value in _piece_scores(policy, piece).items():
            totals[name] = totals.get(name, 0.0) + value * len(piece)
    return {name: total / len(validation) for name, total in totals.items()}


def _piece_scores(policy: ImitationPolicy, validation: TransitionTensors) -> Scores:
    observations, actions = validation.observations, validation.actions
    assert isinstance(actions, torch.Tensor)  # BC refuses Dict action spaces
    with torch.no_grad():
        point, nll = policy.held_out(observations, actions)
        scores = {"nll": float(nll.mean())} if nll is not None else {}
        guess = point.reshape(len(validation), -1)
        held = actions.reshape(len(validation), -1)
        if policy.is_continuous:
            return scores | {"mse": float(((guess - held.float()) ** 2).sum(-1).mean())}
        return scores | {"error_rate": float((guess != held).any(-1).float().mean())}
