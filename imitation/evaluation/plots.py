"""Plots of rewards and visitation on gridworlds (PNG, matplotlib, no display needed)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def plot_grid_maps(path: Path, panels: dict[str, np.ndarray], *, grid_shape: tuple[int, int], title: str) -> None:
    """One heatmap per panel (a per-state vector shown on the grid), side by side, each with
    its own colour scale: learned rewards are only defined up to shift and scale."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(1, len(panels), figsize=(3.6 * len(panels), 3.4), squeeze=False)
    for axis, (name, values) in zip(axes[0], panels.items()):
        image = axis.imshow(np.asarray(values, dtype=float).reshape(grid_shape), cmap="viridis")
        axis.set_title(name, fontsize=10)
        axis.set_xticks([])
        axis.set_yticks([])
        figure.colorbar(image, ax=axis, fraction=0.046, pad=0.04)
    figure.suptitle(title)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)
