"""The run directory: one format for every trainer's output.

    RUN_DIR/
      config.json        everything needed to rebuild the model and rerun (kind, env id, settings)
      model.safetensors  weights (and normaliser statistics); never a pickle
      metrics.json       final numbers
      progress.csv       one row per logged update
      tb/                TensorBoard event files
      *.png              plots

A run is written under `RUN_DIR.partial` and renamed to RUN_DIR only when it is complete; an
existing RUN_DIR is replaced at that moment, not before, so an interrupted or failed run never
destroys the previous one.
"""

from __future__ import annotations

import csv
import json
import math
import os
import shutil
from pathlib import Path
from typing import Any

import torch
from safetensors.torch import load_file, save_file

from imitation.errors import ImitationError

CONFIG_FILE = "config.json"
WEIGHTS_FILE = "model.safetensors"
METRICS_FILE = "metrics.json"
PROGRESS_FILE = "progress.csv"


def _json_ready(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_ready(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if hasattr(value, "item") and callable(value.item):
        return _json_ready(value.item())
    return value


def write_json(path: Path, data: dict[str, Any]) -> None:
    temporary = path.with_name(path.name + ".tmp")
    temporary.write_text(json.dumps(_json_ready(data), indent=2) + "\n")
    os.replace(temporary, path)


class RunWriter:
    """Builds a run directory under `<path>.partial`; `finish()` moves it into place."""

    def __init__(self, path: str | os.PathLike, *, config: dict[str, Any], tensorboard: bool = True, x_axis: str = "step") -> None:
        self.path = Path(path)
        self.x_axis = x_axis
        self.partial = self.path.with_name(self.path.name + ".partial")
        if self.path.exists() and not self.path.is_dir():
            raise ImitationError(f"--out {self.path}: exists and is not a directory")
        try:
            shutil.rmtree(self.partial, ignore_errors=True)
            self.partial.mkdir(parents=True)
        except OSError as error:
            raise ImitationError(f"--out {self.path}: cannot create: {error.strerror or error}") from None
        self.config = config
        write_json(self.partial / CONFIG_FILE, config)
        self._csv_file = open(self.partial / PROGRESS_FILE, "w", newline="")
        self._csv: csv.DictWriter | None = None
        self._history: list[dict[str, float]] = []
        self._tensorboard = None
        if tensorboard:
            from torch.utils.tensorboard import SummaryWriter

            self._tensorboard = SummaryWriter(str(self.partial / "tb"))

    @property
    def history(self) -> list[dict[str, float]]:
        return self._history

    def update_config(self, **entries: Any) -> None:
        """Add what is only known after training (e.g. the policy's architecture) to config.json."""
        self.config.update(entries)
        write_json(self.partial / CONFIG_FILE, self.config)

    def log(self, row: dict[str, float]) -> None:
        """One row of progress (the same keys every time; the `x_axis` column is the x axis)."""
        if self._csv is None:
            self._csv = csv.DictWriter(self._csv_file, fieldnames=list(row))
            self._csv.writeheader()
        self._csv.writerow(row)
        self._csv_file.flush()
        self._history.append(dict(row))
        if self._tensorboard is not None:
            for key, value in row.items():
                if key != self.x_axis and isinstance(value, (int, float)) and math.isfinite(value):
                    self._tensorboard.add_scalar(key, value, int(row[self.x_axis]))

    def save_weights(self, tensors: dict[str, torch.Tensor]) -> None:
        save_file({name: tensor.detach().cpu().contiguous() for name, tensor in tensors.items()}, str(self.partial / WEIGHTS_FILE))

    def file(self, name: str) -> Path:
        """A path inside the run being written (for plots and extra artefacts)."""
        return self.partial / name

    def finish(self, metrics: dict[str, Any]) -> Path:
        write_json(self.partial / METRICS_FILE, metrics)
        self._close_logs()
        if self.path.exists():
            old = self.path.with_name(self.path.name + ".old")
            shutil.rmtree(old, ignore_errors=True)
            os.replace(self.path, old)
            os.replace(self.partial, self.path)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(self.partial, self.path)
        return self.path

    def abort(self) -> None:
        self._close_logs()
        shutil.rmtree(self.partial, ignore_errors=True)

    def __enter__(self) -> RunWriter:
        return self

    def __exit__(self, exc_type: type | None, exc: BaseException | None, tb: Any) -> None:
        # A run that failed or was interrupted leaves nothing behind; a finished one is in place.
        if exc_type is not None:
            self.abort()

    def _close_logs(self) -> None:
        if self._csv_file.closed:
            return
        self._csv_file.close()
        if self._tensorboard is not None:
            self._tensorboard.close()
            self._tensorboard = None


def read_run(path: str | os.PathLike) -> tuple[dict[str, Any], dict[str, torch.Tensor]]:
    """config.json and the weights of a finished run; one-line errors for anything else."""
    run = Path(path)
    if not run.is_dir():
        raise ImitationError(f"{run}: not a run directory (it does not exist or is not a folder)")
    config_path, weights_path = run / CONFIG_FILE, run / WEIGHTS_FILE
    if not config_path.is_file() or not weights_path.is_file():
        raise ImitationError(f"{run}: not a finished run directory (no {CONFIG_FILE} or {WEIGHTS_FILE})")
    try:
        config = json.loads(config_path.read_text())
    except json.JSONDecodeError as error:
        raise ImitationError(f"{config_path}: not valid JSON ({error})") from None
    try:
        weights = load_file(str(weights_path))
    except Exception as error:
        raise ImitationError(f"{weights_path}: unreadable safetensors file ({error})") from None
    return config, weights


def plot_curve(path: Path, history: list[dict[str, float]], *, x: str, ys: list[str], title: str) -> None:
    """A learning-curve PNG of columns `ys` against `x`."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axis = plt.subplots(figsize=(7, 4))
    for y in ys:
        points = [(row[x], row[y]) for row in history if y in row and row[y] is not None and math.isfinite(row[y])]
        if points:
            axis.plot(*zip(*points), label=y)
    axis.set_xlabel(x)
    axis.set_title(title)
    axis.grid(alpha=0.3)
    axis.legend()
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)
