"""Behavioural cloning (theory notes §5): supervised learning of the expert's actions.

    θ* = argmin_θ  E_{(s,a)~D} [ -log π_θ(a|s) ]  -  c_H · E_s[ H[π_θ(·|s)] ]  +  c_2 · ||θ||²

For Discrete actions -log π_θ is the categorical negative log-likelihood (cross-entropy). For
Box actions it is the Gaussian NLL of the state-independent-log-std policy, or (loss="mse") the
squared error of the mean, ||μ_θ(s) - a||². The policy is the same `ActorCritic` PPO trains, so a
BC run can be evaluated, recorded with, or fine-tuned by PPO; its critic stays untrained.

Whole episodes are held out for validation (neighbouring steps are nearly identical, so a
step-level split would flatter the model); training stops after `patience` epochs without a new
best validation loss and the best weights are kept. Observations are normalised with statistics
fitted once on the training demos and saved with the policy.
"""

from __future__ import annotations

import copy
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
import torch
from tqdm import tqdm

from imitation.data.loader import MinibatchLoader, TransitionTensors, resolve_device
from imitation.errors import ImitationError
from imitation.policies import ActorCritic

LOSSES = ("nll", "mse")


@dataclass(kw_only=True)
class BCConfig:
    # Measured on the bundled Pendulum demos (the expert's switching law is the hard part to fit):
    # 64×64 tanh for 50 epochs reaches -396, 256×256 ReLU with early stopping -110.
    epochs: int = 300
    batch_size: int = 256
    learning_rate: float = 1e-3
    hidden_sizes: list[int] = field(default_factory=lambda: [256, 256])
    activation: str = "relu"
    loss: str = "nll"
    entropy_coef: float = 0.0
    l2_coef: float = 0.0
    validation_fraction: float = 0.2
    patience: int = 50
    seed: int = 0
    device: str = "auto"
    threads: int = 1

    def validate(self, continuous: bool) -> None:
        if self.loss not in LOSSES:
            raise ImitationError(f"--loss must be one of {', '.join(LOSSES)}, got {self.loss!r}")
        if self.loss == "mse" and not continuous:
            raise ImitationError("--loss mse is for continuous (Box) actions; discrete actions use nll")
        for name in ("epochs", "batch_size", "patience"):
            if getattr(self, name) < 1:
                raise ImitationError(f"{name} must be at least 1, got {getattr(self, name)}")
        if not 0 < self.learning_rate < 1e30:  # NaN fails too; from ~1e37 Adam's step overflows float32
            raise ImitationError(f"--lr must be a positive number below 1e30, got {self.learning_rate}")


def bc_loss(policy: ActorCritic, batch: TransitionTensors, config: BCConfig) -> tuple[torch.Tensor, dict[str, float]]:
    """The objective above on one batch, and its parts for logging."""
    features = policy.encode(batch.observations)
    distribution = policy.distribution(features)
    if config.loss == "mse":
        fit = ((distribution.mean - batch.actions.reshape(len(batch), -1).float()) ** 2).sum(-1).mean()
    else:
        fit = -policy.log_prob(distribution, batch.actions).mean()
    loss = fit
    if config.entropy_coef:
        loss = loss - config.entropy_coef * policy.entropy(distribution).mean()
    if config.l2_coef:
        l2 = sum((parameter**2).sum() for name, parameter in policy.named_parameters() if name.startswith(("actor_trunk", "action_head")))
        loss = loss + config.l2_coef * l2
    return loss, {"fit": fit.item()}


@torch.no_grad()
def _mean_loss(policy: ActorCritic, data: TransitionTensors, config: BCConfig) -> float:
    policy.eval()
    losses = [bc_loss(policy, batch, config)[1]["fit"] * len(batch) for batch in MinibatchLoader(data, batch_size=4096, shuffle=False)]
    policy.train()
    return float(np.sum(losses) / len(data))


@dataclass
class BCResult:
    policy: ActorCritic
    history: list[dict[str, float]]
    best_epoch: int
    seconds: float


def train_bc(
    policy: ActorCritic,
    train: TransitionTensors,
    validation: TransitionTensors | None,
    config: BCConfig,
    *,
    evaluate: Callable[[ActorCritic], float] | None = None,
    evaluate_every: int = 5,
    log: Callable[[dict[str, float]], None] | None = None,
    progress: bool = True,
) -> BCResult:
    """Fit `policy` to the (s, a) pairs of `train`; early-stop on `validation`'s loss.

    `evaluate(policy)` (e.g. the env return) is logged every `evaluate_every` epochs and at the
    last one. The policy's observation normaliser is refitted to `train` first."""
    config.validate(policy.is_continuous)
    torch.set_num_threads(config.threads)
    torch.manual_seed(config.seed)
    device = resolve_device(config.device)
    policy.to(device).train()
    train, validation = train.to(device), validation.to(device) if validation is not None else None
    if policy.obs_rms is not None:
        policy.obs_rms.reset_parameters()
        policy.update_normalizer(train.observations)
    optimizer = torch.optim.Adam(policy.parameters(), lr=config.learning_rate)
    loader = MinibatchLoader(train, batch_size=config.batch_size, seed=config.seed)

    history: list[dict[str, float]] = []
    best_loss, best_epoch, best_state = float("inf"), 0, copy.deepcopy(policy.state_dict())
    started = time.perf_counter()
    samples = 0
    bar = tqdm(range(1, config.epochs + 1), desc="bc", unit="epoch", disable=None if progress else True, dynamic_ncols=True)
    for epoch in bar:
        fits = []
        for batch in loader:
            loss, parts = bc_loss(policy, batch, config)
            if not torch.isfinite(loss):
                raise ImitationError(f"BC epoch {epoch}: the loss is {loss.item()} (diverged; try a lower learning rate)")
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            fits.append(parts["fit"])
            samples += len(batch)
        validation_loss = _mean_loss(policy, validation, config) if validation is not None and len(validation) else float("nan")
        # Without validation episodes, the training loss decides what "best" means.
        criterion = validation_loss if np.isfinite(validation_loss) else float(np.mean(fits))
        if criterion < best_loss:
            best_loss, best_epoch, best_state = criterion, epoch, copy.deepcopy(policy.state_dict())
        stop = epoch - best_epoch >= config.patience
        row = {
            "epoch": float(epoch),
            "train_loss": float(np.mean(fits)),
            "validation_loss": validation_loss,
            "return": float("nan"),
            "samples_per_second": samples / (time.perf_counter() - started),
        }
        if evaluate is not None and (epoch % evaluate_every == 0 or epoch == config.epochs or stop):
            policy.eval()
            row["return"] = evaluate(policy)
            policy.train()
        history.append(row)
        if log is not None:
            log(row)
        bar.set_postfix(train=f"{row['train_loss']:.3f}", val=f"{validation_loss:.3f}", ret=f"{row['return']:.1f}")
        if stop:
            break
    policy.load_state_dict(best_state)
    return BCResult(policy=policy.eval(), history=history, best_epoch=best_epoch, seconds=time.perf_counter() - started)


def policy_options(config: BCConfig) -> dict[str, Any]:
    """The ActorCritic options a BC run uses (normalised observations, the configured MLP)."""
    return {"hidden_sizes": list(config.hidden_sizes), "activation": config.activation, "normalize_observations": True}
