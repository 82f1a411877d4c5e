"""`export --to` is a registry (imitation/data/export/formats.py): a format registered from outside
the package is written through the command line, and an unknown one is refused naming the
registered ones."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from support import DATASETS

import cli
from imitation.data.export.formats import FORMATS, Format, register
from imitation.data.mcap.reader import DemoFile


def export_returns(demo: str | os.PathLike, destination: str | os.PathLike, *, progress: bool = True) -> dict[str, Any]:
    """A toy format: each episode's return, one per line."""
    returns = [float(episode.rewards.sum()) for episode in DemoFile(demo)]
    Path(destination).write_text("".join(f"{value}\n" for value in returns))
    return {"episodes": len(returns)}


@pytest.fixture
def returns_format() -> Iterator[None]:
    register(Format("returns", "F.txt", export_returns, lambda result: f"{result['episodes']} returns"))
    yield
    del FORMATS["returns"]


def test_a_registered_format_is_written_through_the_command_line(returns_format: None, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    demo, out = DATASETS / "CartPole-v1.mcap", tmp_path / "returns.txt"
    assert cli.main(["export", str(demo), "--to", "returns", str(out)]) == 0
    episodes = list(DemoFile(demo))
    assert capsys.readouterr().out == f"exported {demo} to {out}: {len(episodes)} returns\n"
    assert [float(line) for line in out.read_text().splitlines()] == [float(episode.rewards.sum()) for episode in episodes]


def test_an_unknown_format_names_the_registered_ones(returns_format: None, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["export", str(DATASETS / "CartPole-v1.mcap"), "--to", "rerun", str(tmp_path / "x")]) == 1
    assert capsys.readouterr().err == "error: --to rerun: unknown format; use lerobot DIR or foxglove F2.mcap or returns F.txt\n"
