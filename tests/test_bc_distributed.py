"""Data-parallel BC under torchrun: `torchrun --nproc-per-node 2 -m imitation train bc …` on the CPU
(gloo) matches one process's validation loss, each process reads its own chunks of the demos, a
run killed with SIGKILL resumes to the very weights of an uninterrupted one, and bad use is one
line."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from safetensors.torch import load_file
from support import DATASETS, REPO

import cli
from imitation.algorithms.bc import BCConfig
from imitation.data.dataset import DemoDataset
from imitation.data.loader import MinibatchLoader, split_episodes
from imitation.data.mcap.writer import write_episodes
from imitation.data.shards import chunk_units, plan_shares
from imitation.errors import ImitationError
from imitation.jobs.bc import _split

CARTPOLE = str(DATASETS / "CartPole-v1.mcap")
# Small enough to train in seconds, long enough (30 epochs, a checkpoint every 3) to be killed midway.
SETTINGS = ["--demos", CARTPOLE, "--epochs", "30", "--hidden", "64,64", "--quiet", "--json"]


def _env(tmp: Path) -> dict[str, str]:
    return {**os.environ, "OMP_NUM_THREADS": "1", "HF_HUB_OFFLINE": "1", "HF_HOME": str(tmp / "hf")}


def _bc(out: Path, *extra: str, processes: int | None = None) -> list[str]:
    launcher = ["-m", "torch.distributed.run", "--standalone", "--nproc-per-node", str(processes)] if processes else []
    return [sys.executable, *launcher, "-m", "imitation", "train", "bc", *SETTINGS, "--out", str(out), *extra]


def _finish(process: subprocess.Popen) -> dict:
    stdout, stderr = process.communicate(timeout=300)
    assert process.returncode == 0, stderr[-3000:]
    return json.loads(stdout)  # one JSON document: rank 0 alone prints


def _kill_rank(process: subprocess.Popen, rank: int) -> str:
    """SIGKILL one worker of the torchrun job; torchrun then ends the others. The job's stderr."""
    workers = [int(pid) for pid in Path(f"/proc/{process.pid}/task/{process.pid}/children").read_text().split()]
    victim = next(pid for pid in workers if f"RANK={rank}".encode() in Path(f"/proc/{pid}/environ").read_bytes().split(b"\0"))
    os.kill(victim, signal.SIGKILL)
    _, stderr = process.communicate(timeout=120)
    assert process.returncode != 0, stderr[-3000:]
    return stderr


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, Path | dict]:
    """One process (single/), two (parallel/), and two whose second process was killed after
    their first checkpoint, resumed (resumed/), all with the same settings; side by side, two at
    a time."""
    tmp = tmp_path_factory.mktemp("bc-distributed")
    env = _env(tmp)
    options = {"stdout": subprocess.PIPE, "stderr": subprocess.PIPE, "text": True, "cwd": tmp, "env": env}
    killed = subprocess.Popen(_bc(tmp / "resumed", processes=2), **options)
    single = subprocess.Popen(_bc(tmp / "single"), **options)
    checkpoint = tmp / "resumed.partial" / "checkpoint"
    deadline = time.monotonic() + 120
    while not checkpoint.is_dir():
        assert killed.poll() is None, killed.communicate()[1][-3000:]
        assert time.monotonic() < deadline, "no checkpoint within 2 minutes"
        time.sleep(0.02)
    stderr = _kill_rank(killed, 1)
    # The process left failed for want of the other: its failure keeps the checkpoint.
    assert f"{tmp / 'resumed.partial'} keeps the run's last checkpoint" in stderr or "interrupted:" in stderr, stderr[-3000:]
    stopped_at = json.loads((checkpoint / "state.json").read_text())["trainer"]["epoch"]
    parallel = subprocess.Popen(_bc(tmp / "parallel", processes=2), **options)
    resumed = subprocess.Popen(_bc(tmp / "resumed", "--resume", processes=2), **options)
    return {
        "tmp": tmp,
        "single": _finish(single),
        "parallel": _finish(parallel),
        "resumed": _finish(resumed),
        "stopped_at": stopped_at,
    }


def test_two_processes_match_one_process_validation_loss(runs) -> None:
    single, parallel = runs["single"], runs["parallel"]
    assert parallel["best_validation_loss"] == pytest.approx(single["best_validation_loss"], rel=0.02)
    assert (parallel["train_transitions"], parallel["validation_transitions"]) == (
        single["train_transitions"],
        single["validation_transitions"],
    )
    shares = parallel["data_parallel"]["shares"]
    assert len(shares) == 2 and all(share["train_transitions"] > 0 for share in shares)
    assert sum(share["train_transitions"] for share in shares) == single["train_transitions"]
    assert sum(share["chunks"] for share in shares) == len(_chunks(DemoDataset(CARTPOLE)))
    config = json.loads((Path(parallel["run"]) / "config.json").read_text())
    assert (
        config["world_size"] == 2 and config["split"] == json.loads((Path(single["run"]) / "config.json").read_text())["split"]
    )
    # Written once, by rank 0: the run directory and nothing beside it.
    assert sorted(path.name for path in runs["tmp"].iterdir() if path.name.startswith("parallel")) == ["parallel"]
    assert len((Path(parallel["run"]) / "progress.csv").read_text().splitlines()) == 1 + 30


def test_a_killed_run_resumes_to_the_same_weights(runs) -> None:
    assert 1 < runs["stopped_at"] <= 30, "the run was killed after its first checkpoint, before its end"
    resumed, parallel = (
        load_file(str(Path(runs["resumed"]["run"]) / "model.safetensors")),
        load_file(str(Path(runs["parallel"]["run"]) / "model.safetensors")),
    )
    assert resumed.keys() == parallel.keys()
    assert all(torch.equal(resumed[name], parallel[name]) for name in resumed), "bitwise equal weights"
    assert runs["resumed"]["best_validation_loss"] == runs["parallel"]["best_validation_loss"]


@pytest.fixture(scope="module")
def shards(tmp_path_factory) -> DemoDataset:
    """Three files of CartPole's episodes: chunks shared by several episodes and episodes over
    several chunks (a), an episode of several chunks alone (b), every episode in one chunk (c)."""
    folder = tmp_path_factory.mktemp("shards")
    source = DemoDataset(CARTPOLE)
    episodes = source.read_episodes()
    spaces = {"env_id": source.env_id, "observation_space": source.observation_space, "action_space": source.action_space}
    paths = [
        write_episodes(folder / "a.mcap", episodes[:8], chunk_size=40_000, **spaces),
        write_episodes(folder / "b.mcap", episodes[8:16], chunk_size=3_000, flush_episodes=True, **spaces),
        write_episodes(folder / "c.mcap", episodes[16:20], **spaces),
    ]
    return DemoDataset(paths)


def test_the_files_hold_shared_and_spanning_chunks(shards) -> None:
    a, b, c = shards.files
    chunks = _chunks(shards)
    assert max(len(a.chunks_of(facts)) for facts in a.episodes) > 1 and len({c for c in chunks if c[0] == 0}) < len(a)
    assert all(len(b.chunks_of(facts)) > 1 for facts in b.episodes)
    assert len({c for c in chunks if c[0] == 2}) == 1
    assert [unit.episodes for unit in chunk_units(shards)] == [
        list(range(8)),
        *[[k] for k in range(8, 16)],
        list(range(16, 20)),
    ]


@pytest.mark.parametrize("processes", [2, 3])
def test_shares_are_disjoint_in_chunks_and_cover_them_all(shards, processes) -> None:
    train, _ = split_episodes(len(shards), validation_fraction=0.2, seed=0)
    plan = plan_shares(shards, processes, counted=train)
    chunks = [set(share.chunks) for share in plan]
    every = _chunks(shards)
    assert set().union(*chunks) == every and sum(map(len, chunks)) == len(every)
    assert sorted(k for share in plan for k in share.episodes) == list(range(len(shards)))
    assert all(share.transitions > 0 for share in plan)
    assert plan == plan_shares(shards, processes, counted=train), "every process computes the same plan"


def test_more_processes_than_groups_of_chunks_is_one_line(shards) -> None:
    with pytest.raises(ImitationError, match=r"^torchrun: 11 processes, but the training episodes lie in 10 group"):
        plan_shares(shards, 11)


def test_a_process_reads_only_its_own_chunks(shards, monkeypatch) -> None:
    """What `train bc` loads for each rank (its training and validation episodes) reads the
    chunks of its share and no other."""
    config = BCConfig(validation_fraction=0.2)
    train, _ = split_episodes(len(shards), validation_fraction=0.2, seed=0)
    plan = plan_shares(shards, 2, counted=train)
    paths = [file.path for file in shards.files]
    for rank, share in enumerate(plan):
        fresh = DemoDataset(paths)  # opened before the spy: its summary reads are not chunk reads
        spans: list[tuple[str, int, int]] = []  # (file, first byte, end) of every read
        pread, preadv = os.pread, os.preadv

        def spy_pread(fd: int, length: int, offset: int, _spans=spans, _pread=pread) -> bytes:
            _spans.append((os.readlink(f"/proc/self/fd/{fd}"), offset, offset + length))
            return _pread(fd, length, offset)

        def spy_preadv(fd: int, buffers, offset: int, _spans=spans, _preadv=preadv) -> int:
            length = sum(memoryview(buffer).nbytes for buffer in buffers)
            _spans.append((os.readlink(f"/proc/self/fd/{fd}"), offset, offset + length))
            return _preadv(fd, buffers, offset)

        with monkeypatch.context() as patch:
            patch.setattr(os, "pread", spy_pread)
            patch.setattr(os, "preadv", spy_preadv)
            train_rows, validation_rows, _ = _split(
                fresh, config, offline=True, previous_action=False, share=lambda counted, _mine=share.episodes: _mine
            )
        assert len(train_rows) and validation_rows is not None and len(validation_rows)
        touched = {
            (i, chunk.offset)
            for i, file in enumerate(fresh.files)
            for facts in file.episodes
            for chunk in file.chunks_of(facts)
            for path, start, end in spans
            if path == str(file.path.resolve()) and start < chunk.offset + chunk.length and chunk.offset < end
        }
        assert touched == set(share.chunks), f"rank {rank}"


def _chunks(dataset: DemoDataset) -> set[tuple[int, int]]:
    """(file index, offset) of every chunk an episode of `dataset` lies in."""
    return {
        (i, chunk.offset) for i, file in enumerate(dataset.files) for facts in file.episodes for chunk in file.chunks_of(facts)
    }


def test_a_rank_takes_fixed_full_steps() -> None:
    from imitation.data.loader import TransitionTensors

    rows = 10
    data = TransitionTensors(
        observations=torch.arange(rows, dtype=torch.float32)[:, None],
        actions=torch.zeros(rows, dtype=torch.int64),
        rewards=torch.zeros(rows),
        next_observations=None,
        terminated=torch.zeros(rows, dtype=torch.bool),
        truncated=torch.zeros(rows, dtype=torch.bool),
        episode_index=torch.zeros(rows, dtype=torch.int64),
    )
    loader = MinibatchLoader(data, batch_size=4, steps=7)
    batches = list(loader)
    assert len(loader) == len(batches) == 7 and all(len(batch) == 4 for batch in batches)
    seen = np.concatenate([batch.observations[:, 0].numpy() for batch in batches]).astype(int)
    assert sorted(seen[:10]) == list(range(10)) and sorted(seen[10:20]) == list(range(10)), "whole passes, each shuffled"


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--batch-size", "255"], "error: --batch-size must be a multiple of the 2 torchrun processes"),
        (["--stream-memory", "64"], "error: --stream-memory streams no data under torchrun"),
    ],
)
def test_bad_use_under_torchrun_is_one_line(tmp_path, monkeypatch, capsys, flags, message) -> None:
    monkeypatch.setenv("WORLD_SIZE", "2")
    code = cli.main(["train", "bc", "--demos", CARTPOLE, "--out", str(tmp_path / "run"), "--quiet", *flags])
    err = capsys.readouterr().err
    assert code != 0 and err.startswith(message) and err.count("\n") == 1, err
    assert not any(tmp_path.iterdir())


def test_python_m_imitation_runs_the_command_line() -> None:
    result = subprocess.run(
        [sys.executable, "-m", "imitation", "--help"], capture_output=True, text=True, cwd=REPO, timeout=60
    )
    assert result.returncode == 0 and "train" in result.stdout
