"""Behavioural cloning's settings (`BCConfig`), each field a `train bc` flag (imitation.flags).

Light on purpose: the command line reads it to build `train bc --help` without importing torch.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from imitation.errors import ConfigError
from imitation.flags import flag, hidden_sizes, indices, megabytes, names, seed

if TYPE_CHECKING:
    from imitation.data.frame_transform import FrameTransform

LOSSES = ("nll", "mse")
STEPS = ("all", "human")
PREVIOUS_ACTION = ("auto", "on", "off")
ACTIVATIONS = ("auto", "tanh", "relu")
PREDICTIONS = ("sample", "noise")  # a diffusion policy's denoiser's target (imitation.diffusion_policy.TARGETS)


def _image_size(text: str) -> list[int]:
    from imitation.data.image_resize import parse_image_size

    return list(parse_image_size(text, "--image-size"))


def _crop(text: str) -> list[int]:
    from imitation.envs.pixels import parse_crop

    return list(parse_crop(text))


@dataclass(kw_only=True)
class BCConfig:
    # The defaults beat the trivial baselines on the real robot logs and clone the bundled
    # experts (bench/RESULTS.md): a wide network, early stopping, a little weight decay.
    # A kind registered in imitation.policy_kinds (checked by the job, which imports the registry).
    policy: str = flag(
        "actor-critic",
        metavar="KIND",
        help="the policy kind to train: actor-critic (an MLP, after a CNN for frames, with a categorical or Gaussian "
        "head; what PPO trains too), chunk (action chunking: --history, --chunk, --execute), diffusion (a denoised "
        "chunk: --denoising-steps, --sampling-steps) or another kind registered in imitation.policy_kinds",
    )
    # Sequence kinds (--policy chunk): windows of the demos (imitation.data.windows), and the
    # receding horizon they act with.
    history: int = flag(
        1, metavar="N", help="sequence policies: the observations the policy reads, the current one and N-1 before it"
    )
    chunk: int = flag(1, metavar="H", help="sequence policies: the actions the policy predicts at once")
    execute: int | None = flag(
        None,
        metavar="K",
        help="sequence policies: the actions of a chunk executed before the policy plans again",
        default_text="half the chunk",
    )
    ensemble: float | None = flag(
        None,
        metavar="M",
        help="sequence policies: plan every step and execute the mean of every chunk's action for the step, the i-th "
        "oldest weighted exp(-M i) (ACT's temporal ensembling; Box actions)",
        default_text="off: execute --execute actions of each chunk",
    )
    angles: list[int] | None = flag(
        None,
        name="--angles",
        parse=indices,
        metavar="I,J",
        help="sequence policies on flat observations: the positions that hold angles in radians, read as (cos, sin) so "
        "that a turn through 0 is no jump of 2π (PushT's block angle: 4)",
        default_text="none",
    )
    denoising_steps: int = flag(
        100,
        metavar="K",
        help="diffusion policies: the noise levels the denoiser is trained on (DDPM, squared-cosine schedule)",
    )
    sampling_steps: int = flag(10, metavar="S", help="diffusion policies: the DDIM steps of each plan when acting (S ≤ K)")
    sampling_noise: float = flag(
        1.0,
        metavar="η",
        help="diffusion policies: DDIM's η, the noise each sampling step adds; 0 samples deterministically, 1 adds the "
        "DDPM posterior's (with S = K: DDPM's sampling)",
    )
    members: int = flag(
        1,
        metavar="M",
        help="diffusion policies: denoisers trained side by side from their own initial weights, each sampling step "
        "taking their mean prediction (a deep ensemble; M times the training)",
    )
    observation_noise: float = flag(
        0.0,
        metavar="σ",
        help="sequence policies: add N(0, σ²) to each normalised number of a training window's observations, an "
        "augmentation against fitting a few demos too closely; 0 turns it off",
    )
    prediction: str = flag(
        "sample",
        choices=PREDICTIONS,
        help="diffusion policies: what the denoiser predicts from a noised chunk, the clean chunk or the noise (DDPM's ε)",
    )
    epochs: int = flag(300, metavar="N", help="maximum epochs")
    batch_size: int = flag(256, metavar="B", help="minibatch size")
    learning_rate: float = flag(1e-3, name="--lr", metavar="LR", help="Adam learning rate")
    hidden_sizes: list[int] = flag(
        name="--hidden", parse=hidden_sizes, metavar="256,256", help="MLP layer widths", default_factory=lambda: [256, 256]
    )
    # "auto": tanh below SMALL_DATA training transitions, ReLU from there. A few hundred
    # transitions leave most of the state space between and beyond them, where tanh's bounded
    # units extrapolate to bounded outputs and ReLU's grow without bound; with more data ReLU's
    # sharper fits (an expert's switching law) pay off.
    activation: str = flag(
        "auto",
        choices=ACTIVATIONS,
        help="hidden-layer activation",
        default_text="auto: tanh below 1000 training transitions, relu from there",
    )
    loss: str = flag("nll", choices=LOSSES, help="nll (log-likelihood) or mse (continuous actions only)")
    # Condition on the previous action (policies.py: μ = a_{t-1} + f(s_t, a_{t-1})). "auto": on
    # offline for Box actions that are a recorded stream of set-points, of the observations' shape
    # (joint targets beside joint positions: the state lags the command, and the last target
    # carries the motion the state cannot show), or a recording's command streams whatever their
    # shape (demos that keep a real clock's times, as bags do: an operator's command persists).
    # Off with an env, whose experts act on the state alone, for a simulator's demos of other
    # shapes (an expert's action is a function of the state), and when streamed.
    previous_action: str = flag(
        "auto",
        choices=PREVIOUS_ACTION,
        help="condition the policy on the previous action and predict its change, as for a recorded command stream",
        default_text="auto: on offline when the actions have the observations' shape, set-points such as joint targets "
        "beside joint positions, or are a recording's commands, demos that keep a real clock's times such as a ROS "
        "bag's; off otherwise, with --env and with --stream-memory",
    )
    entropy_coef: float = flag(0.0, name="--entropy", metavar="C", help="entropy bonus coefficient")
    l2_coef: float = flag(1e-4, name="--l2", metavar="C", help="L2 penalty on the policy weights")
    validation_fraction: float = flag(0.2, name="--validation", metavar="F", help="fraction of episodes held out")
    patience: int = flag(50, metavar="N", help="epochs without a better validation loss before stopping")
    # An epoch goes through at least this many samples (several passes over a small recording,
    # each in its own order), so that a few hundred transitions get enough gradient steps.
    epoch_samples: int = flag(
        4096,
        metavar="N",
        help="the fewest samples an epoch goes through: small recordings are passed over several times per epoch",
    )
    # Image observations: frames stacked per image leaf, the random shift in pixels applied to
    # training batches (DrQ), the leaves read, and the CNN (encoders.CNNConfig).
    frame_stack: int | None = flag(
        None,
        metavar="K",
        help="image observations: frames stacked per image",
        default_text="as the demos were recorded, else 1",
    )
    random_shift: int = flag(
        4,
        metavar="P",
        help="image observations: shift training frames by up to P pixels, edges replicated (DrQ); 0 turns it off",
    )
    observation_keys: list[str] | None = flag(
        None,
        parse=names,
        metavar="K,K",
        help="Dict observations: the keys the policy reads",
        default_text="the frames alone for demos recorded with --pixels, every key otherwise",
    )
    cnn: dict[str, Any] | None = None
    # Camera frames cropped to [top, left, height, width] and resized to [height, width] as they
    # load (`FrameTransform`); the policy keeps both, so the env it acts in does the same.
    image_size: list[int] | None = flag(
        None,
        metavar="HxW",
        parse=str,
        convert=_image_size,
        help="camera frames: resize every frame to H×W (area averaging) as the demos load, e.g. 96x96; the policy keeps "
        "the size and the env it is evaluated in resizes its frames the same way",
        default_text="as stored",
    )
    crop: list[int] | None = flag(
        None,
        metavar="T,L,H,W",
        parse=str,
        convert=_crop,
        help="camera frames: keep only this rectangle (top, left, height, width in pixels of the stored frames) before "
        "--image-size resizes them; kept by the policy like the size",
        default_text="the whole frame",
    )
    # Bytes of decoded transitions a streaming run may hold (imitation.data.stream): None loads
    # the demos into memory; a number streams shuffled batches from them.
    stream_memory: int | None = flag(
        None,
        parse=megabytes,
        metavar="MB",
        help="stream shuffled batches from the demos, holding at most MB megabytes of decoded transitions (plus one "
        "episode), for datasets larger than memory (a sequence policy's windows are gathered as episodes stream in); no "
        "baseline scores then",
        default_text="load everything",
    )
    # "human": train on the steps a person drove (the /intervention channels of DAgger's rounds).
    steps: str = flag(
        "all",
        choices=STEPS,
        help="all steps, or only those a person drove, as the /intervention channels of DAgger's round files record "
        "them: human",
    )
    seed: int = flag(0, parse=seed, metavar="S", help="seed")
    device: str = flag("auto", metavar="auto|cpu|cuda", help="where the network runs")
    mixed_precision: bool = flag(
        False,
        help="autocast the network to float16 on CUDA (with a gradient scaler) or bfloat16 on the CPU; weights stay float32",
    )
    # torch CPU threads: convolutions parallelise well; an MLP's small matrices cost more in
    # threads than they gain.
    threads: int | None = flag(
        None, metavar="N", help="torch CPU threads", default_text="every core for a CNN, 1 for an MLP alone"
    )

    def validate(self, continuous: bool) -> None:
        if self.loss not in LOSSES:
            raise ConfigError("loss", f"must be one of {', '.join(LOSSES)}, got {self.loss!r}", owner="BCConfig")
        if self.previous_action not in PREVIOUS_ACTION:
            raise ConfigError(
                "previous_action",
                f"must be one of {', '.join(PREVIOUS_ACTION)}, got {self.previous_action!r}",
                owner="BCConfig",
            )
        if self.loss == "mse" and not continuous:
            raise ConfigError("loss", "mse is for continuous (Box) actions; discrete actions use nll", owner="BCConfig")
        if self.frame_stack is not None and not 1 <= self.frame_stack <= 64:
            raise ConfigError("frame_stack", f"must be in [1, 64], got {self.frame_stack}", owner="BCConfig")
        if self.random_shift < 0:
            raise ConfigError("random_shift", f"must be at least 0 pixels, got {self.random_shift}", owner="BCConfig")
        for name in ("history", "chunk"):
            if not 1 <= getattr(self, name) <= 1024:
                raise ConfigError(name, f"must be in [1, 1024], got {getattr(self, name)}", owner="BCConfig")
        if self.execute is not None and not 1 <= self.execute <= self.chunk:
            raise ConfigError("execute", f"must be in [1, --chunk {self.chunk}], got {self.execute}", owner="BCConfig")
        if self.ensemble is not None and not 0 <= self.ensemble < 1e3:  # NaN fails too
            raise ConfigError("ensemble", f"must be a weight in [0, 1000), got {self.ensemble}", owner="BCConfig")
        if self.ensemble is not None and self.execute is not None:
            raise ConfigError("ensemble", "plans every step; leave --execute unset", owner="BCConfig")
        if not 1 <= self.denoising_steps <= 10_000:
            raise ConfigError("denoising_steps", f"must be in [1, 10000], got {self.denoising_steps}", owner="BCConfig")
        if not 1 <= self.sampling_steps <= self.denoising_steps:
            raise ConfigError(
                "sampling_steps",
                f"must be in [1, --denoising-steps {self.denoising_steps}], got {self.sampling_steps}",
                owner="BCConfig",
            )
        if self.prediction not in PREDICTIONS:
            raise ConfigError(
                "prediction", f"must be one of {', '.join(PREDICTIONS)}, got {self.prediction!r}", owner="BCConfig"
            )
        if not 1 <= self.members <= 64:
            raise ConfigError("members", f"must be in [1, 64], got {self.members}", owner="BCConfig")
        if not 0 <= self.observation_noise <= 10:  # NaN fails too
            raise ConfigError("observation_noise", f"must be in [0, 10], got {self.observation_noise}", owner="BCConfig")
        if not 0 <= self.sampling_noise <= 1:  # NaN fails too
            raise ConfigError("sampling_noise", f"must be in [0, 1], got {self.sampling_noise}", owner="BCConfig")
        if self.threads is not None and not 1 <= self.threads <= 1024:
            raise ConfigError("threads", f"must be in [1, 1024], got {self.threads}", owner="BCConfig")
        if self.steps not in STEPS:
            raise ConfigError("steps", f"must be one of {', '.join(STEPS)}, got {self.steps!r}", owner="BCConfig")
        self.frame_transform()
        if self.stream_memory is not None and self.stream_memory < 1:
            raise ConfigError("stream_memory", f"must be at least 1 byte, got {self.stream_memory}", owner="BCConfig")
        for name in ("epochs", "batch_size", "patience"):
            if getattr(self, name) < 1:
                raise ConfigError(name, f"must be at least 1, got {getattr(self, name)}", owner="BCConfig")
        if not 0 < self.learning_rate < 1e30:  # NaN fails too; from ~1e37 Adam's step overflows float32
            raise ConfigError(
                "learning_rate", f"must be a positive number below 1e30, got {self.learning_rate}", owner="BCConfig"
            )

    def frame_transform(self) -> FrameTransform | None:
        """The crop and size frames load at (None: as stored); ConfigError for malformed ones."""
        from imitation.data.frame_transform import FrameTransform
        from imitation.data.image_resize import MAX_SIDE

        if self.image_size is not None and not _sides(self.image_size, 2, 1):
            raise ConfigError(
                "image_size", f"must be [height, width], each 1 to {MAX_SIDE}, got {self.image_size!r:.40}", owner="BCConfig"
            )
        if self.crop is not None and not (_sides(self.crop, 4, 0) and min(self.crop[2:]) >= 1):
            raise ConfigError(
                "crop",
                f"must be [top, left, height, width], height and width 1 to {MAX_SIDE}, got {self.crop!r:.40}",
                owner="BCConfig",
            )
        if self.image_size is None and self.crop is None:
            return None
        size = (self.image_size[0], self.image_size[1]) if self.image_size is not None else None
        crop = (self.crop[0], self.crop[1], self.crop[2], self.crop[3]) if self.crop is not None else None
        return FrameTransform(size, crop)

    def validate_data_parallel(self, processes: int) -> None:
        """Refuse what a data-parallel run of `processes` processes cannot do."""
        if self.batch_size >= 1 and self.batch_size % processes:
            raise ConfigError(
                "batch_size",
                f"must be a multiple of the {processes} torchrun processes (each takes batch_size / {processes} rows "
                f"a step), got {self.batch_size}",
                owner="BCConfig",
            )
        if self.stream_memory is not None:
            raise ConfigError(
                "stream_memory",
                "streams no data under torchrun (each process loads its share of the demos into memory); leave it unset",
                owner="BCConfig",
            )


def _sides(values: Any, count: int, low: int) -> bool:
    from imitation.data.image_resize import MAX_SIDE

    return (
        isinstance(values, list)
        and len(values) == count
        and all(isinstance(n, int) and not isinstance(n, bool) and low <= n <= MAX_SIDE for n in values)
    )
