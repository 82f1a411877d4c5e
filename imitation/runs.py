"""The run directory: one format for every trainer's output.

    RUN_DIR/
      config.json        everything needed to rebuild the model and rerun (kind, env id, settings)
      model.safetensors  weights (and normaliser statistics); never a pickle
      metrics.json       final numbers
      progress.csv       one row per logged update
      tb/                TensorBoard event files
      *.png              plots

A run is written under `RUN_DIR.partial`, under a lock on RUN_DIR (a second writer fails at
once), and moved to RUN_DIR only when it is complete; an existing RUN_DIR is exchanged with it
in one step at that moment, not before, so an interrupted or failed run never destroys the
previous one.

Trainers that can resume (PPO, with GCL's reward learner when `train irl --method gcl` runs it;
BC; DAgger; tabular MaxEnt/MCE IRL) save a checkpoint into `RUN_DIR.partial/checkpoint/`
(`tensors.safetensors` and `state.json`, see imitation.checkpoints) every tenth of the run and
when Ctrl-C (or SIGTERM) stops them. The partial directory of a run that stops for any reason (an
interruption, a full disk, a failure) is kept when it holds a checkpoint, and removed otherwise;
a failure removes it too when its one checkpoint is the one taken before the first step (a
learner's `at_start`), which holds nothing a rerun would not redo, so that input refused in the
first step leaves nothing behind. A new run refuses to start over a kept one, and
`RunWriter(..., resume=True)` reopens it: the logged rows are cut back to the checkpoint and
the trainer continues from its state. A finished run keeps no checkpoint: nothing resumes it,
so `finish()` removes it once the run is in place.
"""

from __future__ import annotations

import csv
import json
import math
import os
import shutil
from contextlib import suppress
from pathlib import Path
from typing import Any

import torch
from safetensors.torch import load_file, save_file

from imitation.errors import ImitationError, WriteError
from imitation.output import (
    OutputLock,
    as_the_umask_allows,
    check_target,
    os_error,
    remove_stale_locks,
    replace_directory,
    writing,
)

CHECKPOINT_DIR = "checkpoint"
CHECKPOINT_TENSORS = "tensors.safetensors"
CHECKPOINT_STATE = "state.json"
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


def write_json(path: Path, data: dict[str, Any], *, durable: bool = False) -> None:
    temporary = path.with_name(path.name + ".tmp")
    with open(temporary, "w") as stream:
        stream.write(json.dumps(_json_ready(data), indent=2) + "\n")
        if durable:
            stream.flush()
            os.fsync(stream.fileno())
    os.replace(temporary, path)


def _fsync_directory(path: Path) -> None:
    descriptor = os.open(path, os.O_RDONLY)
    try:
        os.fsync(descriptor)
    finally:
        os.close(descriptor)


def save_checkpoint(folder: Path, tensors: dict[str, torch.Tensor], state: dict[str, Any]) -> Path:
    """Write `folder/checkpoint/` so that it always holds one whole checkpoint: the new one is
    written beside it (`checkpoint.new/`), made durable, then swapped in; a crash mid-swap leaves
    `checkpoint.old/`, which `read_checkpoint` falls back to."""
    final, fresh, old = folder / CHECKPOINT_DIR, folder / (CHECKPOINT_DIR + ".new"), folder / (CHECKPOINT_DIR + ".old")
    shutil.rmtree(fresh, ignore_errors=True)
    fresh.mkdir()
    save_file({name: tensor.detach().cpu().contiguous() for name, tensor in tensors.items()}, str(fresh / CHECKPOINT_TENSORS))
    with open(fresh / CHECKPOINT_TENSORS, "rb+") as stream:
        os.fsync(stream.fileno())
    write_json(fresh / CHECKPOINT_STATE, state, durable=True)
    _fsync_directory(fresh)
    if final.exists():
        shutil.rmtree(old, ignore_errors=True)
        os.replace(final, old)
    os.replace(fresh, final)
    _fsync_directory(folder)
    shutil.rmtree(old, ignore_errors=True)
    return final


def has_checkpoint(folder: Path) -> bool:
    return any((folder / name / CHECKPOINT_STATE).is_file() for name in (CHECKPOINT_DIR, CHECKPOINT_DIR + ".old"))


def read_checkpoint(folder: Path) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
    """The checkpoint in `folder` (tensors, state); one-line errors when there is none or it is unreadable."""
    for name in (CHECKPOINT_DIR, CHECKPOINT_DIR + ".old"):
        where = folder / name
        if not (where / CHECKPOINT_STATE).is_file():
            continue
        try:
            state = json.loads((where / CHECKPOINT_STATE).read_text())
            tensors = load_file(str(where / CHECKPOINT_TENSORS))
        except Exception as error:  # noqa: BLE001 - a damaged checkpoint is one line
            raise ImitationError(f"{where}: unreadable checkpoint ({type(error).__name__}: {error})") from None
        if not isinstance(state, dict):
            raise ImitationError(f"{where / CHECKPOINT_STATE}: not a checkpoint state (a JSON object)")
        return tensors, state
    raise ImitationError(f"{folder}: holds no checkpoint (the run stopped before its first one); start again without --resume")


def _differences(saved: Any, given: Any, ignore: set[str], prefix: str = "") -> list[str]:
    """Dotted keys whose values differ between two JSON documents (keys in `ignore` skipped)."""
    if isinstance(saved, dict) and isinstance(given, dict):
        found = []
        for key in sorted(set(saved) | set(given)):
            path = f"{prefix}{key}"
            if path not in ignore:
                found += _differences(saved.get(key), given.get(key), ignore, path + ".")
        return found
    return [] if saved == given else [f"{prefix.rstrip('.')}: {saved!r} there, {given!r} now"]


class RunWriter:
    """Builds a run directory under `<path>.partial`; `finish()` moves it into place.

    With `resume=True` the partial directory of an interrupted run is reopened instead of
    replaced: its config.json must match `config` (keys in `resume_ignore`, dotted, may differ,
    e.g. the device), its logged rows are cut back to its checkpoint, and `resumed` holds the
    trainer's (tensors, state) to continue from."""

    def __init__(
        self,
        path: str | os.PathLike,
        *,
        config: dict[str, Any],
        tensorboard: bool = True,
        x_axis: str = "step",
        resume: bool = False,
        resume_ignore: tuple[str, ...] = (),
    ) -> None:
        self.path = Path(path)
        self.x_axis = x_axis
        self.partial = self.path.with_name(self.path.name + ".partial")
        self.resumed: tuple[dict[str, torch.Tensor], dict[str, Any]] | None = None
        check_target(self.path, directory=True)
        check_target(self.partial, directory=True, flag="the partial run")
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as error:
            raise os_error(self.path, error, "cannot create") from None
        self._lock: OutputLock | None = OutputLock(self.path).acquire()
        try:
            self._open(config, resume, set(resume_ignore), tensorboard=tensorboard, x_axis=x_axis)
        except BaseException:
            self._release()
            raise

    def _open(self, config: dict[str, Any], resume: bool, resume_ignore: set[str], *, tensorboard: bool, x_axis: str) -> None:
        history: list[dict[str, float]] = []
        if resume:
            history = self._reopen(config, resume_ignore)
        elif has_checkpoint(self.partial):
            raise ImitationError(
                f"{self.partial}: holds an interrupted run with a checkpoint; continue it with --resume, "
                "or delete it to start over"
            )
        else:
            with writing(self.path):
                shutil.rmtree(self.partial, ignore_errors=True)
                self.partial.mkdir()
        self.config = config
        self._started_with = json.loads(json.dumps(_json_ready(config)))
        with writing(self.partial / CONFIG_FILE):
            write_json(self.partial / CONFIG_FILE, config)
            # Kept open for the run's life: log() appends rows; closed by _close_logs().
            self._csv_file = open(self.partial / PROGRESS_FILE, "w", newline="")  # noqa: SIM115
        self._csv: csv.DictWriter | None = None
        self._history: list[dict[str, float]] = []
        # Whether the checkpoint on disk holds work done (a reopened one is assumed to).
        self._progress_checkpointed = resume
        self._tensorboard = None
        if tensorboard:
            from torch.utils.tensorboard import SummaryWriter

            # purge_step hides the events an interrupted run logged after its checkpoint.
            purge = int(history[-1][x_axis]) + 1 if history else None
            self._tensorboard = SummaryWriter(str(self.partial / "tb"), purge_step=purge)
        for row in history:
            self.log(row, tensorboard=False)

    def _reopen(self, config: dict[str, Any], ignore: set[str]) -> list[dict[str, float]]:
        """Check that the partial run matches `config` and load its checkpoint; the rows logged
        up to the checkpoint."""
        from imitation.checkpoints import floats

        if not self.partial.is_dir():
            raise ImitationError(
                f"--resume: {self.partial} does not exist, so there is no interrupted run to continue; start without --resume"
            )
        tensors, state = read_checkpoint(self.partial)
        remove_stale_locks(self.partial)  # those of writers killed with the run (a DAgger round's)
        # The settings the run was started with, as its checkpoint recorded them: config.json
        # may since have gained what training found (the policy's architecture), written
        # before a final evaluation that a Ctrl-C can still stop.
        saved = state.get("config")
        if not isinstance(saved, dict):
            try:
                saved = json.loads((self.partial / CONFIG_FILE).read_text())
            except (OSError, json.JSONDecodeError) as error:
                raise ImitationError(f"--resume: {self.partial / CONFIG_FILE} is unreadable ({error})") from None
        differences = _differences(saved, json.loads(json.dumps(_json_ready(config))), ignore)
        if any(difference.startswith("demo_fingerprints") for difference in differences):
            raise ImitationError(
                f"--resume: the demo files changed since {self.partial} was started (their size or checksums differ); "
                "resume with the same files, or start again without --resume"
            )
        if differences:
            raise ImitationError(
                f"--resume: {self.partial} was started with other settings ({differences[0]}); "
                "resume with the same ones, or start again without --resume"
            )
        self.resumed = (tensors, state.get("trainer", {}))
        try:
            return [floats(row) for row in state.get("history", [])]
        except (TypeError, ValueError, AttributeError) as error:
            raise ImitationError(f"{self.partial / CHECKPOINT_DIR}: unreadable checkpoint (logged rows: {error})") from None

    @property
    def history(self) -> list[dict[str, float]]:
        return self._history

    def update_config(self, **entries: Any) -> None:
        """Add what is only known after training (e.g. the policy's architecture) to config.json."""
        self.config.update(entries)
        with writing(self.partial / CONFIG_FILE):
            write_json(self.partial / CONFIG_FILE, self.config)

    def log(self, row: dict[str, float], *, tensorboard: bool = True) -> None:
        """One row of progress (the same keys every time; the `x_axis` column is the x axis)."""
        with writing(self.partial / PROGRESS_FILE):
            if self._csv is None:
                self._csv = csv.DictWriter(self._csv_file, fieldnames=list(row))
                self._csv.writeheader()
            self._csv.writerow(row)
            self._csv_file.flush()
        self._history.append(dict(row))
        if self._tensorboard is not None and tensorboard:
            for key, value in row.items():
                if key != self.x_axis and isinstance(value, (int, float)) and math.isfinite(value):
                    self._tensorboard.add_scalar(key, value, int(row[self.x_axis]))

    def save_weights(self, tensors: dict[str, torch.Tensor]) -> None:
        with writing(self.partial / WEIGHTS_FILE):
            save_file(
                {name: tensor.detach().cpu().contiguous() for name, tensor in tensors.items()},
                str(self.partial / WEIGHTS_FILE),
            )
            as_the_umask_allows(self.partial / WEIGHTS_FILE)

    def save_checkpoint(self, tensors: dict[str, torch.Tensor], state: dict[str, Any]) -> None:
        """Save a trainer's checkpoint with the rows logged so far (see `save_checkpoint`)."""
        self._save_checkpoint(tensors, state)
        self._progress_checkpointed = True

    def save_start_checkpoint(self, tensors: dict[str, torch.Tensor], state: dict[str, Any]) -> None:
        """Save the checkpoint taken before the first step: kept by an interruption, not by a failure."""
        self._save_checkpoint(tensors, state)

    def _save_checkpoint(self, tensors: dict[str, torch.Tensor], state: dict[str, Any]) -> None:
        with writing(self.partial / CHECKPOINT_DIR):
            save_checkpoint(self.partial, tensors, {"history": self._history, "trainer": state, "config": self._started_with})

    def file(self, name: str) -> Path:
        """A path inside the run being written (for plots and extra artefacts)."""
        return self.partial / name

    def finish(self, metrics: dict[str, Any]) -> Path:
        """Write metrics.json and move the run into place; its checkpoint, needed only to resume
        it, does not stay (see `_drop_checkpoint`)."""
        with writing(self.path):
            write_json(self.partial / METRICS_FILE, metrics)
            self._close_logs()
            replace_directory(self.partial, self.path)
        self._drop_checkpoint()
        self._release()
        return self.path

    def _drop_checkpoint(self) -> None:
        """Remove the finished run's checkpoint once the run is in place (until then a crash
        leaves a resumable partial run; the weights are never touched). It leaves the run in one
        rename, to the partial name: free by now, under our lock, and cleared by the next run if
        we die before deleting it. Best effort: a checkpoint left behind is only a duplicate."""
        with suppress(OSError):
            if (self.path / CHECKPOINT_DIR).is_dir() and not os.path.lexists(self.partial):
                os.replace(self.path / CHECKPOINT_DIR, self.partial)
            shutil.rmtree(self.partial, ignore_errors=True)
        for name in (CHECKPOINT_DIR, CHECKPOINT_DIR + ".new", CHECKPOINT_DIR + ".old"):
            shutil.rmtree(self.path / name, ignore_errors=True)

    def abort(self, *, keep_checkpoint: bool = False, keep_start: bool = False) -> bool:
        """Stop after a failure. The partial run is removed, unless `keep_checkpoint` and it holds
        a checkpoint to resume from, one of work done or, with `keep_start`, the one taken before
        the first step; whether it was kept."""
        with suppress(OSError):
            self._close_logs()
        kept = keep_checkpoint and (self._progress_checkpointed or keep_start) and has_checkpoint(self.partial)
        if not kept:
            shutil.rmtree(self.partial, ignore_errors=True)
        self._release()
        return kept

    def _release(self) -> None:
        if self._lock is not None:
            self._lock.release()
            self._lock = None

    def __enter__(self) -> RunWriter:
        return self

    def __exit__(self, exc_type: type | None, exc: BaseException | None, tb: Any) -> None:
        # A failure never deletes a checkpoint of work done: what stopped the run (a full disk,
        # a lost process of a torchrun job, a bug) may be mended, and the run continued with --resume.
        if exc_type is None:
            return
        kept = self.abort(keep_checkpoint=True, keep_start=isinstance(exc, KeyboardInterrupt))
        if kept and isinstance(exc, WriteError):
            exc.args = (
                f"{exc}; {self.partial} keeps the run's last checkpoint: make room, then run the same command with --resume",
            )
        elif kept and isinstance(exc, ImitationError):
            exc.args = (
                f"{exc}; {self.partial} keeps the run's last checkpoint: once that is mended, run the same command with "
                "--resume (or delete it to start over)",
            )

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
    missing = [path.name for path in (config_path, weights_path) if not os.path.lexists(path)]
    if missing:
        raise ImitationError(f"{run}: not a finished run directory (no {' or '.join(missing)})")
    for path in (config_path, weights_path):
        if not path.is_file():
            raise ImitationError(f"{path}: is not a regular file")
    try:
        config = json.loads(config_path.read_bytes())
    except OSError as error:
        raise os_error(config_path, error, "cannot read") from None
    except (ValueError, RecursionError) as error:  # ValueError: not JSON, or not UTF-8
        raise ImitationError(f"{config_path}: not valid JSON ({type(error).__name__}: {str(error)[:200]})") from None
    if not isinstance(config, dict):
        raise ImitationError(f"{config_path}: not a run's config (a JSON object), but a {type(config).__name__}")
    try:
        with open(weights_path, "rb"):
            pass
        weights = load_file(str(weights_path))
    except OSError as error:
        raise os_error(weights_path, error, "cannot read") from None
    except Exception as error:
        raise ImitationError(f"{weights_path}: unreadable safetensors file ({str(error)[:200]})") from None
    return config, weights
