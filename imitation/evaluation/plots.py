"""Plots of rewards, visitation and returns (PNG, matplotlib, no display needed)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

import gymnasium as gym
import numpy as np


def plot_curve(
    path: Path,
    history: list[dict[str, float]],
    *,
    x: str,
    ys: list[str],
    title: str,
    references: dict[str, float] | None = None,
) -> None:
    """A learning-curve PNG of columns `ys` against `x` (non-finite points left out), with
    `references` (e.g. baselines' values) as dashed horizontal lines."""
    plt = _pyplot()
    figure, axis = plt.subplots(figsize=(7, 4))
    for y in ys:
        points = [(row[x], row[y]) for row in history if y in row and row[y] is not None and np.isfinite(row[y])]
        if points:
            axis.plot(*zip(*points), label=y)
    for index, (name, value) in enumerate((references or {}).items()):
        if np.isfinite(value):
            axis.axhline(value, linestyle="--", linewidth=1, color=f"C{len(ys) + index}", label=name)
    axis.set_xlabel(x)
    axis.set_title(title)
    axis.grid(alpha=0.3)
    if axis.get_legend_handles_labels()[0]:
        axis.legend()
    else:  # e.g. a run too short to finish an episode
        axis.text(0.5, 0.5, "no finite values yet", transform=axis.transAxes, ha="center", va="center")
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


def plot_grid_maps(path: Path, panels: dict[str, np.ndarray], *, grid_shape: tuple[int, int], title: str) -> None:
    """One heatmap per panel (a per-state vector shown on the grid), side by side, each with
    its own colour scale: learned rewards are only defined up to shift and scale."""
    plt = _pyplot()
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


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_reward_scatter(
    path: Path, true_values: np.ndarray, rewards: dict[str, np.ndarray], *, xlabel: str, title: str
) -> None:
    """Each reward against the true one, one panel each (their scales are arbitrary)."""
    plt = _pyplot()
    figure, axes = plt.subplots(1, len(rewards), figsize=(3.6 * len(rewards), 3.4), squeeze=False)
    for axis, (name, values) in zip(axes[0], rewards.items()):
        axis.scatter(true_values, values, s=4, alpha=0.4)
        axis.set_xlabel(xlabel, fontsize=9)
        axis.set_ylabel(f"{name} reward", fontsize=9)
        axis.grid(alpha=0.3)
    figure.suptitle(title)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


def slice_dimensions(observations: np.ndarray, space: gym.spaces.Box) -> tuple[int, int]:
    """The two observation dimensions the demos vary most in, relative to the space's extent
    (the demos' own spread where the space is unbounded): the most telling 2-D slice."""
    flat = observations.reshape(len(observations), -1)
    spread = flat.std(axis=0)
    extent = (space.high - space.low).reshape(-1).astype(np.float64)
    relative = np.where(np.isfinite(extent) & (extent > 0), spread / np.where(np.isfinite(extent), extent, 1.0), 1.0)
    first, second = np.argsort(-relative, kind="stable")[:2]
    return int(first), int(second)


def plot_state_slices(
    path: Path,
    observations: np.ndarray,
    actions: np.ndarray,
    rewards: dict[str, Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]],
    space: gym.spaces.Box,
    *,
    title: str,
    resolution: int = 60,
) -> None:
    """Each reward R(s, a, s) over a grid of two observation dimensions (`slice_dimensions`),
    the other dimensions and the action held at the demos' mean (mode for discrete actions);
    the demo states are overlaid."""
    plt = _pyplot()
    flat = observations.reshape(len(observations), -1).astype(np.float64)
    first, second = slice_dimensions(observations, space)
    low, high = flat.min(axis=0), flat.max(axis=0)
    margin = 0.25 * (high - low) + 1e-6
    xs = np.linspace(low[first] - margin[first], high[first] + margin[first], resolution)
    ys = np.linspace(low[second] - margin[second], high[second] + margin[second], resolution)
    grid_x, grid_y = np.meshgrid(xs, ys)
    states = np.repeat(flat.mean(axis=0)[None], grid_x.size, axis=0)
    states[:, first], states[:, second] = grid_x.reshape(-1), grid_y.reshape(-1)
    states = np.clip(states, space.low.reshape(-1), space.high.reshape(-1)).astype(space.dtype).reshape((-1, *space.shape))
    if np.issubdtype(actions.dtype, np.integer):
        values, counts = np.unique(actions, axis=0, return_counts=True)
        typical_action = values[np.argmax(counts)]
    else:
        typical_action = actions.mean(axis=0).astype(actions.dtype)
    batch_actions = np.repeat(np.asarray(typical_action)[None], len(states), axis=0)
    figure, axes = plt.subplots(1, len(rewards), figsize=(4.2 * len(rewards), 3.6), squeeze=False)
    for axis, (name, reward) in zip(axes[0], rewards.items()):
        image = axis.pcolormesh(
            grid_x,
            grid_y,
            np.asarray(reward(states, batch_actions, states), dtype=float).reshape(grid_x.shape),
            cmap="viridis",
            shading="auto",
        )
        axis.scatter(flat[:, first], flat[:, second], s=2, c="white", alpha=0.3)
        axis.set_xlabel(f"observation[{first}]")
        axis.set_ylabel(f"observation[{second}]")
        axis.set_title(name, fontsize=10)
        figure.colorbar(image, ax=axis, fraction=0.046, pad=0.04)
    figure.suptitle(title, fontsize=10)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


def plot_return_distributions(
    path: Path, returns: dict[str, Sequence[float]], references: dict[str, float], *, title: str
) -> None:
    """Each group's returns as points over a box, with reference returns as horizontal lines."""
    plt = _pyplot()
    names = [name for name, values in returns.items() if len(values)]
    figure, axis = plt.subplots(figsize=(1.6 * len(names) + 3, 3.8))
    axis.boxplot([returns[name] for name in names], tick_labels=names, showfliers=False)
    for position, name in enumerate(names, start=1):
        values = np.asarray(returns[name], dtype=float)
        axis.scatter(
            position + np.linspace(-0.12, 0.12, len(values)) if len(values) > 1 else [position], values, s=16, zorder=3
        )
    for (label, value), style in zip(references.items(), ("--", ":", "-.")):
        axis.axhline(value, linestyle=style, color="grey", label=f"{label} {value:.1f}")
    axis.set_ylabel("true return")
    axis.set_title(title, fontsize=10)
    axis.grid(alpha=0.3)
    axis.legend(fontsize=8)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)
