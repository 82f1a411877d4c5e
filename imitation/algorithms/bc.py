"""Behavioural cloning (docs/THEORY.md §5): supervised learning of the expert's actions.

    θ* = argmin_θ  E_{(s,a)~D} [ ℓ_θ(s, a) ]

with ℓ_θ the policy kind's loss (`ImitationPolicy.imitation_loss`, `train bc --policy`). For the
default kind, the actor-critic,

    ℓ_θ(s, a) = -log π_θ(a|s)  -  c_H · H[π_θ(·|s)]  +  c_2 · ||θ||²

For Discrete and MultiDiscrete actions -log π_θ is the categorical negative log-likelihood
(cross-entropy) of the class index a - start of the demo's action a. For
Box actions it is the Gaussian NLL of the state-independent-log-std policy, or (loss="mse") the
squared error of the mean, ||μ_θ(s) - a||². With `previous_action` (a recorded stream of
set-points) the policy is π_θ(a_t | s_t, a_{t-1}) = N(a_{t-1} + f_θ(s_t, a_{t-1}), σ²), its head in
units of the actions' changes (policies.py). The policy is the same `ActorCritic` PPO trains, so a
BC run can be evaluated, recorded with, or fine-tuned by PPO; its critic stays untrained.

Whole episodes are held out for validation (neighbouring steps are nearly identical, so a
step-level split would flatter the model); training stops after `patience` epochs without a new
best validation loss and the best weights are kept. Observations are normalised with statistics
fitted once on the training demos and saved with the policy.

Data-parallel (`parallel`: W processes under torchrun, each holding a disjoint share D_r of the
transitions): process r draws minibatches B_r of batch_size / W rows from D_r, and every step
applies the averaged gradient

    g = (1/W) Σ_r ∇_θ L(θ; B_r)

which, the B_r being equal in size, is the gradient of the loss on their union: the single-process
step on a minibatch of batch_size rows. Every process takes the steps one process would take on all
the data; the normalisers' statistics, the training and validation losses are those of all the
data, pooled across the processes.
"""

from __future__ import annotations

import copy
import math
import os
from collections.abc import Callable
from typing import Any, Protocol, cast

import gymnasium as gym
import numpy as np
import torch

from imitation.algorithms.bc_config import BCConfig
from imitation.checkpoints import CheckpointData, CheckpointReader, CheckpointWriter, TrainingClock
from imitation.data.loader import MinibatchLoader, TransitionTensors
from imitation.data.stream import StreamingLoader
from imitation.data.windows import WindowBatch, gather_windows, window_index
from imitation.encoders import CNNConfig, cnn_activation_count, cnn_weight_count
from imitation.errors import ConfigError, ImitationError
from imitation.flat_adam import FlatAdam
from imitation.mlp import mlp_weight_count
from imitation.observation_encoding import observation_layout, observation_size
from imitation.policies import RunningMeanStd, action_logits_size
from imitation.policy_protocol import ImitationObjective, ImitationPolicy
from imitation.tensors import resolve_device


class DataParallel(Protocol):
    """The processes of a data-parallel run, as a learner uses them (`imitation.jobs.distributed`
    implements it). Every process must make the same calls in the same order."""

    rank: int
    world_size: int

    def all_sum(self, tensor: torch.Tensor) -> None: ...  # in place: the sum over the processes

    def broadcast(self, tensor: torch.Tensor) -> None: ...  # in place: rank 0's values

    def all_gather(self, tensor: torch.Tensor) -> torch.Tensor: ...  # every process's, stacked by rank


def default_threads(policy: ImitationPolicy) -> int:
    """Every core this process may use for a policy with a CNN, else one."""
    return len(os.sched_getaffinity(0)) if policy.reads_images else 1


def objective(config: BCConfig) -> ImitationObjective:
    """The settings of BC's objective a policy kind's loss reads."""
    return ImitationObjective(config.loss, config.entropy_coef, config.l2_coef, config.random_shift, config.observation_noise)


def bc_loss(
    policy: ImitationPolicy, batch: TransitionTensors | WindowBatch, config: BCConfig
) -> tuple[torch.Tensor, dict[str, float]]:
    """The objective above on one batch (the policy kind's `imitation_loss`), and its parts for logging."""
    loss, fit = policy.imitation_loss(batch, objective(config))
    return loss, {"fit": fit.item()}


def _mean_loss(policy: ImitationPolicy, data: TransitionTensors | StreamingLoader, config: BCConfig) -> float:
    total, count = _loss_sum(policy, data, config)
    return float(total / count)


def _loss_sum(policy: ImitationPolicy, data: TransitionTensors | StreamingLoader, config: BCConfig) -> tuple[float, int]:
    """The fit's sum over `data`, and its rows: in-memory data in pieces of 4096 rows, or of a
    training batch for a policy with a CNN, whose activations then stay within a training step's."""
    streamed = isinstance(data, StreamingLoader)
    piece = config.batch_size if policy.reads_images else 4096
    batches = (
        data
        if isinstance(data, StreamingLoader)
        else MinibatchLoader(data, batch_size=piece, shuffle=False, gather=windows_of(policy, data))
    )
    count = data.transitions if isinstance(data, StreamingLoader) else len(data)
    device = next(policy.parameters()).device
    with torch.no_grad():
        policy.eval()
        losses = [bc_loss(policy, batch.to(device) if streamed else batch, config)[1]["fit"] * len(batch) for batch in batches]
        policy.train()
        return np.sum(losses), count


def _merged_moments(
    parallel: DataParallel, count: torch.Tensor, mean: torch.Tensor, var: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Every process's (count, mean, variance) pooled (Chan et al.):
    n = Σ n_r, μ = Σ n_r μ_r / n, σ² = Σ n_r (σ_r² + (μ_r − μ)²) / n."""
    total = count.double().clone()
    parallel.all_sum(total)
    pooled_mean = mean.double() * count
    parallel.all_sum(pooled_mean)
    pooled_mean /= total
    spread = count * (var.double() + (mean.double() - pooled_mean) ** 2)
    parallel.all_sum(spread)
    return total, pooled_mean, spread / total


def _merge_statistics(statistics: RunningMeanStd, parallel: DataParallel) -> None:
    """A normaliser fitted to this process's share, refitted to all the processes' data. Each
    share's statistics started from the prior count ε, which the pooled count holds once."""
    count, mean, var = _merged_moments(parallel, statistics.count, statistics.mean, statistics.var)
    statistics.mean.copy_(mean)
    statistics.var.copy_(var)
    statistics.count.copy_(count - (parallel.world_size - 1) * statistics.epsilon)


def _moments_merge(parallel: DataParallel) -> Callable[[int, torch.Tensor, torch.Tensor], tuple[torch.Tensor, torch.Tensor]]:
    """`ImitationPolicy.fit_action_normalizer`'s merge across the processes of `parallel`."""

    def merge(rows: int, mean: torch.Tensor, std: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        count = torch.tensor(float(rows), dtype=torch.float64, device=mean.device)
        _, pooled_mean, var = _merged_moments(parallel, count, mean, std**2)
        return pooled_mean, var.sqrt()

    return merge


def windows_of(policy: ImitationPolicy, data: TransitionTensors) -> Callable[[torch.Tensor], WindowBatch] | None:
    """How minibatches of `data` are gathered for `policy`: as windows of its length
    (`imitation.data.windows`), or, for a policy of single transitions, None (the transitions
    themselves)."""
    if policy.window is None:
        return None
    index = window_index(data.episode_index.cpu().numpy(), policy.window)
    return lambda rows: gather_windows(data, index, rows.cpu().numpy())


def _rank_loader(
    train: TransitionTensors, config: BCConfig, parallel: DataParallel, policy: ImitationPolicy
) -> MinibatchLoader:
    """This process's minibatches: batch_size / W rows each, as many per epoch as one process
    would take on all the data, shuffled by a generator of this rank's own."""
    rows = torch.tensor(len(train), dtype=torch.float64)
    parallel.all_sum(rows)
    total = int(rows)
    passes = max(1, -(-config.epoch_samples // total))
    steps = math.ceil(passes * total / config.batch_size)
    seed = int(np.random.SeedSequence([config.seed, parallel.rank]).generate_state(1)[0])
    return MinibatchLoader(
        train,
        batch_size=config.batch_size // parallel.world_size,
        seed=seed,
        steps=steps,
        gather=windows_of(policy, train),
    )


def _fit_normalizers(policy: ImitationPolicy, stream: StreamingLoader, device: torch.device) -> None:
    """The normalisers' statistics from one ordered pass over a stream (skipped when the policy
    has none to fit): the observations' folded in batch by batch, the actions' from all of them
    (one small column)."""
    fits_actions = policy.is_continuous and policy.config.normalize_actions
    if not policy.observation_normalizers and not fits_actions:
        return
    actions = []
    for batch in stream.in_order():
        policy.update_normalizer(batch.to(device).observations)
        assert isinstance(batch.actions, torch.Tensor)  # a policy takes no Dict actions
        actions.append(batch.actions)
    policy.fit_action_normalizer(torch.cat(actions).to(device), None)


class BehaviouralCloning:
    """The learner: `policy` fitted to the (s, a) pairs of `train`, one epoch per step, stopping
    early on `validation`'s loss; the best weights so far are kept and are the result.

    `evaluate(policy)` (e.g. the env return) is logged every `evaluate_every` epochs and at the
    last one. The policy's observation normaliser is refitted to `train` first.

    `train` and `validation` may be streams (`BCConfig.stream_memory`): batches are then decoded
    as they are needed, and the normalisers fitted in one extra ordered pass when the policy has
    any. Policies of the previous action take in-memory data only.

    With `parallel`, `train` and `validation` are this process's shares of in-memory data and
    the learner one of W data-parallel replicas (the module docstring): every process must run
    it the same way, step for step; `evaluate` is for rank 0 alone."""

    name = "BC"
    unit = "epoch"

    def __init__(
        self,
        policy: ImitationPolicy,
        train: TransitionTensors | StreamingLoader,
        validation: TransitionTensors | StreamingLoader | None,
        config: BCConfig,
        *,
        evaluate: Callable[[ImitationPolicy], float] | None = None,
        evaluate_every: int = 5,
        parallel: DataParallel | None = None,
    ) -> None:
        config.validate(policy.is_continuous)
        if parallel is not None:
            config.validate_data_parallel(parallel.world_size)
        self.parallel = parallel
        torch.set_num_threads(config.threads or default_threads(policy))
        torch.manual_seed(config.seed)
        device = resolve_device(config.device)
        self.policy = policy.to(device).train()
        self.device = device
        self.validation: TransitionTensors | StreamingLoader | None
        self.loader: MinibatchLoader | StreamingLoader
        for statistics in policy.observation_normalizers:
            statistics.reset_parameters()
        if isinstance(train, StreamingLoader):
            if policy.config.previous_action:
                raise ConfigError(
                    "stream_memory", "streams no data for a policy of the previous action; leave it unset", owner="BCConfig"
                )
            # A sequence policy's streams gather its windows (`StreamingLoader`'s window).
            assert validation is None or isinstance(validation, StreamingLoader)
            assert train.window == policy.window and (validation is None or validation.window == policy.window)
            self.validation, self.loader = validation, train
            _fit_normalizers(policy, train, device)
        else:
            assert not isinstance(validation, StreamingLoader)  # streamed validation goes with streamed training
            self.train, self.validation = train.to(device), validation.to(device) if validation is not None else None
            policy.update_normalizer(self.train.observations)
            assert isinstance(self.train.actions, torch.Tensor)  # a policy takes no Dict actions
            if parallel is None:
                policy.fit_action_normalizer(self.train.actions, self.train.observations)
                self.loader = MinibatchLoader(
                    self.train,
                    batch_size=config.batch_size,
                    seed=config.seed,
                    min_samples=config.epoch_samples,
                    gather=windows_of(policy, self.train),
                )
            else:
                for statistics in policy.observation_normalizers:
                    _merge_statistics(statistics, parallel)
                policy.fit_action_normalizer(self.train.actions, self.train.observations, merge=_moments_merge(parallel))
                self.loader = _rank_loader(self.train, config, parallel, policy)
        self.config = config
        self.total = config.epochs
        self.evaluate, self.evaluate_every = evaluate, evaluate_every
        self.optimizer = FlatAdam(policy.parameters(), lr=config.learning_rate)
        if parallel is not None:
            parallel.broadcast(self.optimizer.flat)  # the replicas start from rank 0's weights
        self.half = torch.float16 if device.type == "cuda" else torch.bfloat16
        self.scaler = torch.amp.GradScaler(device.type, enabled=config.mixed_precision and device.type == "cuda")
        self.epochs = 0
        self.best_loss, self.best_epoch, self.best_state = float("inf"), 0, copy.deepcopy(policy.state_dict())
        self.samples = 0
        self.stopped = False
        self.clock = TrainingClock()
        # Within the current epoch: the batches taken and their fits, the loader's generator as
        # the epoch began (it draws the epoch's order), and whether Ctrl-C asked to stop (`stop_when`).
        self.batch, self.epoch_start = 0, self.loader.generator_state()
        self.fits: list[float] = []
        self._stop_requested: Callable[[], bool] = lambda: False
        self._within = ""

    @property
    def completed(self) -> int:
        return self.epochs

    @property
    def done(self) -> bool:
        return self.stopped or self.epochs >= self.total

    def position(self) -> str:
        if self.batch:
            return f"batch {self.batch} of {len(self.loader)} in epoch {self.epochs + 1} of {self.total}"
        return f"epoch {self.epochs} of {self.total}"

    def stop_when(self, requested: Callable[[], bool]) -> None:
        """Stop an epoch between minibatches once `requested()` (`imitation.jobs.loop.Interruptible`)."""
        self._stop_requested = requested

    def within(self) -> str:
        return self._within

    def progress(self, row: dict[str, float]) -> dict[str, str]:
        shown = {"train": f"{row['train_loss']:.3f}", "val": f"{row['validation_loss']:.3f}"}
        return shown | ({"ret": f"{row['return']:.1f}"} if np.isfinite(row["return"]) else {})

    def step(self) -> dict[str, float] | None:
        """One epoch of minibatch steps on the loss; then the validation loss, the best weights,
        the early stop, and the evaluation when one is due. Stopped between minibatches at a
        request (`stop_when`), None: the epoch goes on from there (after a checkpoint, on --resume)."""
        self.clock.start()
        epoch = self.epochs + 1
        if self.batch == 0:
            self.epoch_start, self.fits = self.loader.generator_state(), []
        else:  # the epoch stopped midway: its order drawn again, the batches taken left out
            self.loader.set_generator_state(self.epoch_start)
        fits = self.fits
        streamed = isinstance(self.loader, StreamingLoader)
        batches = len(self.loader)
        taken = 0
        for batch in self.loader.batches(skip=self.batch):
            if taken and self._stop_requested():
                self._within = ""
                return None
            self._within = f"batch {self.batch + 1} of {batches}"
            if streamed:  # streamed batches arrive on the CPU
                batch = batch.to(self.device)
            with torch.autocast(self.device.type, dtype=self.half, enabled=self.config.mixed_precision):
                loss, parts = bc_loss(self.policy, batch, self.config)
            if not torch.isfinite(loss):
                raise ImitationError(f"BC epoch {epoch}: the loss is {loss.item()} (diverged; try a lower learning rate)")
            self.optimizer.zero_grad(set_to_none=True)
            self.scaler.scale(loss).backward()
            if self.parallel is not None:
                self._average_gradient(self.parallel)
            self.scaler.step(cast(torch.optim.Optimizer, self.optimizer))  # it reads only param_groups and step()
            self.scaler.update()
            self.policy.after_update()
            fits.append(parts["fit"])
            self.samples += len(batch) * (self.parallel.world_size if self.parallel is not None else 1)
            self.batch, taken = self.batch + 1, taken + 1
        self.batch = 0
        self._within = "validation loss"
        validation = self.validation
        if self.parallel is None:
            train_loss = float(np.mean(fits))
            validation_loss = (
                _mean_loss(self.policy, validation, self.config)
                if validation is not None and len(validation)
                else float("nan")
            )
        else:
            train_loss, validation_loss = self._pooled_losses(fits, self.parallel)
        # Without validation episodes, the training loss decides what "best" means.
        criterion = validation_loss if np.isfinite(validation_loss) else train_loss
        if criterion < self.best_loss:
            self.best_loss, self.best_epoch, self.best_state = criterion, epoch, copy.deepcopy(self.policy.state_dict())
        self.epochs = epoch
        self.stopped = epoch - self.best_epoch >= self.config.patience
        row = {
            "epoch": float(epoch),
            "train_loss": train_loss,
            "validation_loss": validation_loss,
            "return": float("nan"),
            "samples_per_second": self.samples / self.clock.seconds,
        }
        if self.evaluate is not None and (epoch % self.evaluate_every == 0 or self.done):
            self._within = "evaluation"
            self.policy.eval()
            row["return"] = self.evaluate(self.policy)
            self.policy.train()
        self._within = ""
        if self.done:
            self.policy.load_state_dict(self.best_state)
            self.policy.eval()
        return row

    def _average_gradient(self, parallel: DataParallel) -> None:
        """g ← (1/W) Σ_r g_r in FlatAdam's one flat gradient buffer: a single all-reduce per step,
        which is what DistributedDataParallel does with one bucket, without its per-parameter
        hooks and its copies of the gradients into a bucket and back (the buffer already is one).
        """
        gradient = self.optimizer.flat_gradient()
        parallel.all_sum(gradient)
        gradient.div_(parallel.world_size)

    def _pooled_losses(self, fits: list[float], parallel: DataParallel) -> tuple[float, float]:
        """The epoch's mean training fit and the validation loss over every process's share (NaN
        where no process holds validation data), in one all-reduce."""
        validation = self.validation
        held, rows = (
            _loss_sum(self.policy, validation, self.config) if validation is not None and len(validation) else (0.0, 0)
        )
        sums = torch.tensor([float(np.sum(fits)), len(fits), held, rows], dtype=torch.float64)
        parallel.all_sum(sums)
        train, steps, held_sum, held_rows = sums.tolist()
        return train / steps, held_sum / held_rows if held_rows else float("nan")

    def state_dict(self) -> CheckpointData:
        """Everything to continue at the next epoch as if never stopped: weights, the best
        weights so far, Adam's moments, the shuffling and torch generators; within an epoch
        (stopped between minibatches), the batches taken, their fits and the shuffling
        generator as the epoch began, to draw its order again."""
        checkpoint = CheckpointWriter(
            epoch=self.epochs + 1,
            best_loss=self.best_loss,
            best_epoch=self.best_epoch,
            samples=self.samples,
            scaler=self.scaler.state_dict(),
        )
        checkpoint.module("policy", self.policy.state_dict())
        checkpoint.module("best", self.best_state)
        checkpoint.optimizer(self.optimizer)
        checkpoint.rng()
        checkpoint.clock(self.clock)
        checkpoint.tensors["loader.generator"] = self.loader.generator_state()
        if self.batch:
            checkpoint.tensors["loader.epoch_start"] = self.epoch_start
            checkpoint.state |= {"batch": self.batch, "fits": list(self.fits)}
        if self.parallel is not None:
            # Every process's place in its own data and random streams, so that each resumes where it was.
            checkpoint.tensors |= {
                "loader.generators": self.parallel.all_gather(self.loader.generator_state()),
                "rng.torch.ranks": self.parallel.all_gather(torch.get_rng_state()),
            }
            checkpoint.state["world_size"] = self.parallel.world_size
        return checkpoint.data()

    def load_state_dict(self, checkpoint: CheckpointData) -> None:
        with CheckpointReader(checkpoint, "BC") as saved:
            self.policy.load_state_dict(saved.module("policy"))
            device = next(self.policy.parameters()).device
            self.best_state = {name: t.to(device) for name, t in saved.module("best").items()}
            saved.optimizer(self.optimizer)
            saved.rng()
            if saved.state.get("scaler"):
                self.scaler.load_state_dict(saved.state["scaler"])
            self.loader.set_generator_state(saved.tensors["loader.generator"])
            if self.parallel is not None:
                self._restore_ranks(saved, self.parallel)
            self.best_loss = float("inf") if saved.state["best_loss"] is None else float(saved.state["best_loss"])
            self.best_epoch, self.samples = int(saved.state["best_epoch"]), int(saved.state["samples"])
            saved.clock(self.clock)
            self.epochs = saved.counter("epoch", "next epoch", 1, self.total + 1) - 1
            self.batch = saved.counter("batch", "batch within the epoch", 0, len(self.loader), default=0)
            if self.batch:
                self.epoch_start = saved.tensors["loader.epoch_start"].clone()
                self.fits = [float(fit) for fit in saved.state["fits"]]

    def _restore_ranks(self, checkpoint: CheckpointReader, parallel: DataParallel) -> None:
        """This process's loader and torch generators from a data-parallel checkpoint."""
        saved = int(checkpoint.state.get("world_size", 1))
        if saved != parallel.world_size:
            raise ImitationError(
                f"--resume: the run was trained by {saved} process(es), not {parallel.world_size}; "
                f"resume it with torchrun --nproc-per-node {saved}"
            )
        self.loader.set_generator_state(checkpoint.tensors["loader.generators"][parallel.rank].clone())
        torch.set_rng_state(checkpoint.tensors["rng.torch.ranks"][parallel.rank].clone())


def fit(learner: BehaviouralCloning) -> list[dict[str, float]]:
    """BC to its end in one go, without checkpoints (DAgger's rounds; a job runs it in the
    shared loop instead); the rows of its epochs."""
    rows = []
    while not learner.done:
        row = learner.step()
        assert row is not None  # stopped within an epoch only when `stop_when` asks, which nothing here does
        rows.append(row)
    return rows


# Bytes per weight in training: the weights, their gradients, Adam's two moments, the best
# weights kept and a checkpoint's snapshot, float32 each.
WEIGHT_BYTES = 6 * 4


def training_step_bytes(
    observation_space: gym.Space,
    action_space: gym.Space,
    config: BCConfig,
    *,
    keys: list[str] | None,
    frames: int,
    transitions: int,
) -> tuple[int, int]:
    """(weights, bytes) of a BC policy for these spaces (as the policy reads them: image leaves
    stacked and transformed) and what one training step holds beyond the data, on a batch of
    `config.batch_size` rows or all of an epoch's (at least `config.epoch_samples`, drawn from
    `transitions`), whichever is fewer, estimated without building anything: `WEIGHT_BYTES` per weight; per sample and
    image leaf of k·H·W·C pixels, the shifted uint8 copy and two float32 copies (scaled, laid out
    as planes), and for each of the CNN's activations its output, its ReLU's and their gradient
    (float32 each)."""
    layout = observation_layout(observation_space, keys, frames)
    cnn = CNNConfig.from_json(config.cnn or {})
    hidden = list(config.hidden_sizes)
    if layout is None:
        inputs, cnn_weights, per_sample = observation_size(observation_space), 0, 0
    else:
        inputs = layout.vector_size + cnn.features * len(layout.images)
        cnn_weights = sum(
            cnn_weight_count(leaf.frames * leaf.channels, leaf.height, leaf.width, cnn) for leaf in layout.images
        )
        per_sample = sum(
            leaf.frames * leaf.height * leaf.width * leaf.channels * (1 + 2 * 4)
            + 3 * 4 * cnn_activation_count(leaf.height, leaf.width, cnn)
            for leaf in layout.images
        )
    weights = (
        cnn_weights
        + 2 * mlp_weight_count(inputs, hidden, 0)
        + (hidden or [inputs])[-1] * (action_logits_size(action_space) + 1)
    )
    rows = min(config.batch_size, max(transitions, config.epoch_samples))
    return weights, weights * WEIGHT_BYTES + per_sample * rows


SMALL_DATA = 1000  # training transitions below which "auto" picks tanh (see BCConfig.activation)


def policy_options(config: BCConfig, transitions: int | None = None) -> dict[str, Any]:
    """The `PolicyConfig` options a BC run uses (its kind aside): normalised observations and
    Box actions, the configured MLP, "auto" resolved for `transitions` training transitions
    (unknown: ReLU), and a sequence kind's windows and horizon."""
    activation = config.activation
    if activation == "auto":
        activation = "tanh" if transitions is not None and transitions < SMALL_DATA else "relu"
    return {
        "hidden_sizes": list(config.hidden_sizes),
        "activation": activation,
        "normalize_observations": True,
        "normalize_actions": True,
        "history": config.history,
        "chunk": config.chunk,
        "execute": config.execute,
        "ensemble": config.ensemble,
        "angles": list(config.angles or []),
        "denoising_steps": config.denoising_steps,
        "sampling_steps": config.sampling_steps,
        "sampling_noise": config.sampling_noise,
        "prediction": config.prediction,
        "members": config.members,
    }
