"""Behavioural cloning (theory notes §5): supervised learning of the expert's actions.

    θ* = argmin_θ  E_{(s,a)~D} [ -log π_θ(a|s) ]  -  c_H · E_s[ H[π_θ(·|s)] ]  +  c_2 · ||θ||²

For Discrete and MultiDiscrete actions -log π_θ is the categorical negative log-likelihood
(cross-entropy) of the class index a - start of the demo's action a. For
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

from imitation.checkpoints import (
    CheckpointData,
    Checkpointing,
    StopAtBoundary,
    TrainingInterrupted,
    checked_counter,
    floats,
    optimizer_checkpoint,
    prefixed,
    restore_optimizer,
    restore_rng,
    rng_checkpoint,
    snapshot,
    unprefixed,
)
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
        fit = -policy.log_prob(distribution, policy.from_env_action(batch.actions)).mean()
    loss = fit
    if config.entropy_coef:
        loss = loss - config.entropy_coef * policy.entropy(distribution).mean()
    if config.l2_coef:
        l2 = sum((parameter**2).sum() for name, parameter in policy.named_parameters() if name.startswith(("actor_trunk", "action_head")))
        loss = loss + config.l2_coef * l2
    return loss, {"fit": fit.item()}


def _mean_loss(policy: ActorCritic, data: TransitionTensors, config: BCConfig) -> float:
    with torch.no_grad():
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
    checkpoints: Checkpointing | None = None,
) -> BCResult:
    """Fit `policy` to the (s, a) pairs of `train`; early-stop on `validation`'s loss.

    `evaluate(policy)` (e.g. the env return) is logged every `evaluate_every` epochs and at the
    last one. The policy's observation normaliser is refitted to `train` first.

    With `checkpoints`, a checkpoint is saved every tenth of the epochs (by default), Ctrl-C
    stops after the current epoch with a checkpoint saved (TrainingInterrupted), and a run given
    `checkpoints.resume` continues from one exactly as if it had not stopped."""
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
    first_epoch = 1
    if checkpoints is not None and checkpoints.resume is not None:
        first_epoch, best_loss, best_epoch, best_state, samples, elapsed = restore_bc_checkpoint(
            checkpoints.resume, policy=policy, optimizer=optimizer, loader=loader, history=history, device=device
        )
        first_epoch = checked_counter(first_epoch, "next epoch", 1, config.epochs + 1)
        started -= elapsed
    bar = tqdm(range(first_epoch, config.epochs + 1), initial=first_epoch - 1, total=config.epochs, desc="bc", unit="epoch", disable=None if progress else True, dynamic_ncols=True)
    with StopAtBoundary(enabled=checkpoints is not None) as interrupt:
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
            # A checkpoint every tenth of the epochs; Ctrl-C stops here (a finished run just finishes).
            interrupted = interrupt.requested and epoch < config.epochs
            if checkpoints is not None and (interrupted or (epoch % checkpoints.interval(config.epochs) == 0 and epoch < config.epochs)):
                checkpoints.save(*bc_checkpoint(
                    epoch + 1, best_loss, best_epoch, best_state, samples, time.perf_counter() - started,
                    policy=policy, optimizer=optimizer, loader=loader, history=history,
                ))
            if interrupted:
                bar.close()
                raise TrainingInterrupted(f"BC stopped after epoch {epoch} of {config.epochs}")
    policy.load_state_dict(best_state)
    return BCResult(policy=policy.eval(), history=history, best_epoch=best_epoch, seconds=time.perf_counter() - started)


def bc_checkpoint(
    next_epoch: int, best_loss: float, best_epoch: int, best_state: dict[str, torch.Tensor], samples: int, seconds: float, *,
    policy: ActorCritic, optimizer: torch.optim.Optimizer, loader: MinibatchLoader, history: list[dict[str, float]],
) -> CheckpointData:
    """Everything `restore_bc_checkpoint` needs to continue at `next_epoch` as if never stopped:
    weights, the best weights so far, Adam's moments, the shuffling and torch generators."""
    optimizer_tensors, optimizer_state = optimizer_checkpoint(optimizer, "optimizer")
    rng_tensors, rng_state = rng_checkpoint()
    tensors = (
        prefixed("policy", policy.state_dict()) | prefixed("best", best_state)
        | optimizer_tensors | rng_tensors | {"loader.generator": loader.generator_state()}
    )
    state = {
        "epoch": next_epoch, "best_loss": best_loss, "best_epoch": best_epoch, "samples": samples, "seconds": seconds,
        "optimizer": optimizer_state, "rng": rng_state, "history": history,
    }
    return snapshot(tensors, state)


def restore_bc_checkpoint(
    checkpoint: CheckpointData, *, policy: ActorCritic, optimizer: torch.optim.Optimizer, loader: MinibatchLoader,
    history: list[dict[str, float]], device: torch.device,
) -> tuple[int, float, int, dict[str, torch.Tensor], int, float]:
    """Load a `bc_checkpoint` (history is filled in place); returns (next epoch, best loss, best
    epoch, best weights, samples seen, seconds trained so far)."""
    tensors, state = checkpoint
    try:
        policy.load_state_dict(unprefixed("policy", tensors))
        best_state = {name: t.to(device) for name, t in unprefixed("best", tensors).items()}
        restore_optimizer(optimizer, tensors, state["optimizer"], "optimizer")
        restore_rng(tensors, state["rng"])
        loader.set_generator_state(tensors["loader.generator"])
        history += [floats(row) for row in state["history"]]
        best_loss = float("inf") if state["best_loss"] is None else float(state["best_loss"])
        return int(state["epoch"]), best_loss, int(state["best_epoch"]), best_state, int(state["samples"]), float(state["seconds"])
    except (KeyError, TypeError, ValueError, RuntimeError) as error:
        raise ImitationError(f"the checkpoint does not fit this BC run ({type(error).__name__}: {str(error).splitlines()[0]})") from None


def policy_options(config: BCConfig) -> dict[str, Any]:
    """The ActorCritic options a BC run uses (normalised observations, the configured MLP)."""
    return {"hidden_sizes": list(config.hidden_sizes), "activation": config.activation, "normalize_observations": True}
