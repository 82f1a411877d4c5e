"""convert's sources are a registry (imitation/data/convert/sources.py): a source added from
outside the package, one module and one `register`, is recognised, named by --from, refused the
options it does not take, and converted through the command line like the built-in ones."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import cli
from imitation.data.convert.converted import Converted
from imitation.data.convert.sources import SOURCES, Request, Source, register
from imitation.data.mcap.reader import DemoFile
from imitation.data.types import Episode


def csv_episodes(request: Request) -> tuple[Converted, str | None]:
    """A toy format: one episode, a row per step, the observation's two columns then the action."""
    rows = np.loadtxt(request.path, delimiter=",", dtype=np.float32, ndmin=2)
    episode = Episode(observations=rows[:, :2], actions=rows[:-1, 2], rewards=np.zeros(len(rows) - 1), truncated=True)
    box = gym.spaces.Box(-np.inf, np.inf, (2,), np.float32)
    converted = Converted([episode], box, gym.spaces.Box(-np.inf, np.inf, (), np.float32), source=f"csv {request.path}")
    return converted, request.env_id


@pytest.fixture
def csv_source() -> Iterator[None]:
    register(Source("csv", csv_episodes, lambda path, head: path.suffix == ".csv"))
    yield
    del SOURCES["csv"]


def write_csv(path: Path) -> Path:
    path.write_text("0,1,0.5\n1,2,0.25\n2,3,0\n")
    return path


def test_a_registered_source_converts_through_the_command_line(csv_source: None, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    source = write_csv(tmp_path / "steps.csv")
    assert cli.main(["convert", str(source), "--out", str(tmp_path / "a.mcap"), "--quiet", "--json"]) == 0  # recognised
    assert json.loads(capsys.readouterr().out.splitlines()[-1])["from"] == "csv"
    assert cli.main(["convert", str(source), "--from", "csv", "--out", str(tmp_path / "b.mcap"), "--quiet"]) == 0
    for name in ("a.mcap", "b.mcap"):
        (episode,) = DemoFile(tmp_path / name).read_episodes()
        assert np.array_equal(episode.observations, [[0, 1], [1, 2], [2, 3]]) and np.array_equal(episode.actions, [0.5, 0.25])


def test_a_registered_source_is_refused_the_options_it_does_not_take(csv_source: None, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    source = write_csv(tmp_path / "steps.csv")
    for flag, value, said in [
        ("--image-size", "8x8", "--image-size resizes the cameras of bags, LeRobot datasets and zarr replay buffers"),
        ("--map", "m.yaml", "--map is for ROS bags"),
    ]:
        assert cli.main(["convert", str(source), flag, value, "--out", str(tmp_path / "c.mcap")]) == 1
        assert capsys.readouterr().err == f"error: {said}; {source} is a csv source\n"
    assert not (tmp_path / "c.mcap").exists()


def test_an_unknown_source_names_the_registered_ones(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["convert", str(write_csv(tmp_path / "steps.csv")), "--from", "csv", "--out", str(tmp_path / "d.mcap")]) == 1
    assert capsys.readouterr().err == f"error: --from csv: unknown source; use one of {', '.join(SOURCES)}\n"


def test_a_source_takes_only_options_convert_has() -> None:
    with pytest.raises(ValueError, match=r"source odd: takes \['fps'\]"):
        Source("odd", csv_episodes, lambda path, head: False, frozenset({"fps"}))
