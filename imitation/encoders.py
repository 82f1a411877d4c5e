"""Image encoders for pixel observations, and the random-shift augmentation BC trains them with.

A frame stack of images, (k, H, W, C) per sample and already scaled to floats by the policy
(standardised per channel, or divided by 255), is fed to a convolutional network as k·C input
planes. The default torso is the "Nature CNN" of Mnih et al. (2015):

    conv 32 × 8×8 stride 4 → ReLU → conv 64 × 4×4 stride 2 → ReLU → conv 64 × 3×3 stride 1 → ReLU
    → flatten → linear to 512 → ReLU

and `CNNConfig` sets its widths, kernels, strides and output size (small frames need smaller
kernels: the Nature torso needs at least 36×36 pixels).

Random shift (DrQ, Kostrikov et al. 2021; robomimic's crop randomisation): each sample's frames
are translated together by (dy, dx) drawn uniformly from {−p, …, p}², the border replicated,

    x'[i, j] = x[clip(i + dy, 0, H − 1), clip(j + dx, 0, W − 1)],

which is the pad-by-p-then-crop of DrQ written as one gather on the uint8 frames.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import torch
from torch import nn


@dataclass(kw_only=True)
class CNNConfig:
    """The convolutional torso: one conv layer per entry of `channels`, then a linear layer."""

    channels: list[int] = field(default_factory=lambda: [32, 64, 64])
    kernels: list[int] = field(default_factory=lambda: [8, 4, 3])
    strides: list[int] = field(default_factory=lambda: [4, 2, 1])
    features: int = 512

    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    @staticmethod
    def from_json(data: Any) -> CNNConfig:
        """From a run's config; TypeError or ValueError for anything malformed."""
        if not isinstance(data, dict):
            raise TypeError(f"the CNN config is a {type(data).__name__}, not an object")
        config = CNNConfig(**data)
        lists = (config.channels, config.kernels, config.strides)
        if (
            not all(
                isinstance(values, list)
                and 1 <= len(values) <= 8
                and all(isinstance(v, int) and not isinstance(v, bool) and 1 <= v <= 1024 for v in values)
                for values in lists
            )
            or len({len(values) for values in lists}) != 1
        ):
            raise ValueError("the CNN's channels, kernels and strides are lists of one length (≤ 8) of integers in [1, 1024]")
        if isinstance(config.features, bool) or not isinstance(config.features, int) or not 1 <= config.features <= 8192:
            raise ValueError(f"the CNN's features must be an integer in [1, 8192], got {config.features!r}")
        return config


class ImageEncoder(nn.Module):
    """Scaled float frames (batch, k, H, W, C) → features (batch, config.features)."""

    def __init__(self, frames: int, height: int, width: int, channels: int, config: CNNConfig) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        planes = frames * channels
        for out, kernel, stride in zip(config.channels, config.kernels, config.strides):
            layers += [nn.Conv2d(planes, out, kernel, stride), nn.ReLU()]
            planes = out
        self.convolutions = nn.Sequential(*layers, nn.Flatten())
        with torch.no_grad():
            size = self.convolutions(torch.zeros(1, frames * channels, height, width)).shape[1]
        self.linear = nn.Sequential(nn.Linear(size, config.features), nn.ReLU())
        self.features = config.features

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        batch, k, height, width, channels = frames.shape
        planes = frames.permute(0, 1, 4, 2, 3).reshape(batch, k * channels, height, width)
        return self.linear(self.convolutions(planes))


def conv_output_sides(height: int, width: int, config: CNNConfig) -> tuple[int, int]:
    """Height and width of the last convolution's output (≤ 0: the frames are too small)."""
    for kernel, stride in zip(config.kernels, config.strides):
        height, width = (height - kernel) // stride + 1, (width - kernel) // stride + 1
    return height, width


def cnn_weight_count(planes: int, height: int, width: int, config: CNNConfig) -> int:
    """How many numbers such a CNN's weights hold (biases not counted), computed without building
    it, so that a crafted config is refused before anything that size is allocated."""
    count = 0
    for out, kernel in zip(config.channels, config.kernels):
        count += planes * out * kernel * kernel
        planes = out
    rows, columns = conv_output_sides(height, width, config)
    return count + planes * max(rows, 0) * max(columns, 0) * config.features


def cnn_activation_count(height: int, width: int, config: CNNConfig) -> int:
    """Numbers the convolutions' outputs hold for one sample (what a training step keeps for the
    backward pass, per conv layer, besides its input)."""
    count = 0
    for out, kernel, stride in zip(config.channels, config.kernels, config.strides):
        height, width = (height - kernel) // stride + 1, (width - kernel) // stride + 1
        count += out * max(height, 0) * max(width, 0)
    return count


def random_shift(frames: torch.Tensor, pad: int, generator: torch.Generator | None = None) -> torch.Tensor:
    """Each sample of (batch, k, H, W, C) frames shifted by its own (dy, dx) in {−pad, …, pad}²,
    edges replicated (module docstring); the k frames of a sample move together."""
    if pad <= 0:
        return frames
    batch, _, height, width, _ = frames.shape
    device = frames.device
    dy, dx = torch.randint(0, 2 * pad + 1, (2, batch), generator=generator, device=device) - pad
    rows = (torch.arange(height, device=device)[None] + dy[:, None]).clamp(0, height - 1)
    columns = (torch.arange(width, device=device)[None] + dx[:, None]).clamp(0, width - 1)
    samples = torch.arange(batch, device=device)[:, None, None]
    # Indices split by a slice put the indexed dimensions first: (batch, H, W, k, C).
    shifted = frames[samples, :, rows[:, :, None], columns[:, None, :]]
    return shifted.permute(0, 3, 1, 2, 4)
