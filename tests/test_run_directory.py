"""A finished run directory keeps no checkpoint (issue 17): only resuming an interrupted run reads
one, so `RunWriter.finish` removes it, after the run is in place and without ever leaving the
finished directory without its weights. (Through the command line: tests/test_cli_ppo.py.)"""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import torch

from imitation import runs
from imitation.errors import WriteError
from imitation.runs import RunWriter, has_checkpoint, read_checkpoint, read_run

FINISHED = ["config.json", "metrics.json", "model.safetensors", "progress.csv"]


def run_with_checkpoints(path: Path, weight: float) -> RunWriter:
    """A run that logged a row, saved its weights and two checkpoints (the second replaces the first)."""
    run = RunWriter(path, config={"kind": "test", "weight": weight}, tensorboard=False)
    run.log({"step": 1.0, "loss": weight})
    run.save_weights({"w": torch.full((3,), weight)})
    for epoch in (1, 2):
        run.save_checkpoint({"w": torch.full((3,), weight)}, {"epoch": epoch})
    assert has_checkpoint(run.partial) and read_checkpoint(run.partial)[1]["trainer"] == {"epoch": 2}
    return run


def test_finish_removes_the_checkpoint_and_keeps_the_run(tmp_path: Path) -> None:
    out = tmp_path / "run"
    run_with_checkpoints(out, 1.0).finish({"done": True})
    assert sorted(p.name for p in out.iterdir()) == FINISHED
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]  # no partial run, no leftover beside it
    config, weights = read_run(out)
    assert config["weight"] == 1.0 and torch.equal(weights["w"], torch.ones(3))

    # Replacing a finished run (the exchange path): the new run, again without a checkpoint.
    run_with_checkpoints(out, 2.0).finish({"done": True})
    assert sorted(p.name for p in out.iterdir()) == FINISHED
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]
    assert torch.equal(read_run(out)[1]["w"], torch.full((3,), 2.0))


def test_the_checkpoint_goes_only_once_the_finished_run_is_in_place(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    out = tmp_path / "run"
    run_with_checkpoints(out, 1.0).finish({})
    run = run_with_checkpoints(out, 2.0)
    seen: list[tuple[list[str], bool]] = []
    replace = os.replace

    def watching(source, target) -> None:  # the moment the checkpoint leaves the run directory
        if Path(source) == out / runs.CHECKPOINT_DIR:
            seen.append((sorted(p.name for p in out.iterdir()), torch.equal(read_run(out)[1]["w"], torch.full((3,), 2.0))))
        replace(source, target)

    monkeypatch.setattr(runs.os, "replace", watching)
    run.finish({})
    monkeypatch.undo()
    assert seen == [(["checkpoint", *FINISHED], True)], "the new run, weights and all, was in place first"
    assert sorted(p.name for p in out.iterdir()) == FINISHED


def test_a_failed_move_into_place_keeps_the_checkpoint_to_resume(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A failure before the run is in place (here the exchange itself) must not cost the checkpoint."""
    out = tmp_path / "run"

    def failing(new: Path, target: Path) -> None:
        raise OSError(28, "No space left on device", str(target))

    monkeypatch.setattr(runs, "replace_directory", failing)
    with pytest.raises(WriteError, match="disk full.*keeps the run.s last checkpoint"):
        with run_with_checkpoints(out, 1.0) as run:
            run.finish({})
    partial = tmp_path / "run.partial"
    assert not out.exists() and has_checkpoint(partial) and read_checkpoint(partial)[1]["trainer"] == {"epoch": 2}


def test_a_checkpoint_that_cannot_be_removed_does_not_fail_the_finished_run(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    out = tmp_path / "run"
    run = run_with_checkpoints(out, 1.0)
    replace = os.replace

    def refusing(source, target) -> None:
        if Path(source) == out / runs.CHECKPOINT_DIR:
            raise PermissionError(13, "Permission denied", str(source))
        replace(source, target)

    monkeypatch.setattr(runs.os, "replace", refusing)
    monkeypatch.setattr(runs.shutil, "rmtree", lambda path, ignore_errors=False: None)
    assert run.finish({"done": True}) == out
    monkeypatch.undo()
    # Finished and readable; the checkpoint it could not drop is a harmless duplicate.
    assert sorted(p.name for p in out.iterdir()) == ["checkpoint", *FINISHED]
    assert read_run(out)[0]["weight"] == 1.0


def test_resuming_removes_the_lock_files_of_killed_writers_but_not_a_held_one(tmp_path: Path) -> None:
    """A DAgger round's writer killed with the run leaves `.round-NN.mcap.lock` in the partial
    run; continuing the run clears it (and every other lock no process holds)."""
    from imitation.output import OutputLock

    run = run_with_checkpoints(tmp_path / "run", 1.0)
    rounds = run.partial / "rounds"
    rounds.mkdir()
    stale = rounds / ".round-03.mcap.lock"
    stale.write_text("12345 2026-12-06T00:00:00\n")
    held = OutputLock(rounds / "round-04.mcap").acquire()
    run._close_logs()
    run._release()
    resumed = RunWriter(tmp_path / "run", config={"kind": "test", "weight": 1.0}, tensorboard=False, resume=True)
    assert not stale.exists() and held.path.exists()
    held.release()
    resumed.finish({})
    assert not list((tmp_path / "run").rglob("*.lock"))


def test_a_lock_file_hard_linked_to_another_file_is_refused_and_the_file_kept(tmp_path: Path) -> None:
    from imitation.errors import ImitationError
    from imitation.output import OutputLock

    victim = tmp_path / "victim.txt"
    victim.write_text("keep me")
    os.link(victim, tmp_path / ".x.mcap.lock")
    with pytest.raises(ImitationError, match=r"\.x\.mcap\.lock: not a lock file of this program \(a hard link to another file"):
        OutputLock(tmp_path / "x.mcap").acquire()
    assert victim.read_text() == "keep me"


def test_a_failure_drops_a_start_checkpoint_but_an_interruption_or_a_later_checkpoint_keeps_it(tmp_path: Path) -> None:
    """The checkpoint taken before the first step holds no work: a failure (input refused in the
    first step) leaves nothing behind, a Ctrl-C keeps it to resume from, and so does a failure
    once a checkpoint of work done replaced it."""

    def started(name: str) -> RunWriter:
        run = RunWriter(tmp_path / name, config={"kind": "test"}, tensorboard=False)
        run.save_start_checkpoint({"w": torch.zeros(3)}, {"epoch": 0})
        return run

    with pytest.raises(ValueError), started("failed"):
        raise ValueError("refused in the first step")
    with pytest.raises(KeyboardInterrupt), started("interrupted"):
        raise KeyboardInterrupt
    with pytest.raises(ValueError), started("failed later") as run:
        run.save_checkpoint({"w": torch.ones(3)}, {"epoch": 1})
        raise ValueError("failed in the second step")
    assert not (tmp_path / "failed.partial").exists()
    assert read_checkpoint(tmp_path / "interrupted.partial")[1]["trainer"] == {"epoch": 0}
    assert read_checkpoint(tmp_path / "failed later.partial")[1]["trainer"] == {"epoch": 1}
