"""The `train` commands are a table (imitation/train_commands.py): a learner registered from
outside the package, with nothing but its config and one entry, becomes `train NAME` with its
flags and help, runs through the command line (JSON and the lines it prints), and a sweep knows
its default metric."""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

import cli
from imitation.commands import Command, Options, RunOutput, settings
from imitation.flags import flag, given
from imitation.train_commands import LEARNERS, TrainLearner, Trained, default_metric, register


@dataclass(kw_only=True)
class CountConfig:
    to: int = flag(3, metavar="N", help="how far the toy learner counts")


def train_count(args) -> Trained:
    """A toy learner: counts to --to, logging each number as its 'loss', into --out."""
    config = CountConfig(**given(args, CountConfig))
    Path(args.out).mkdir(parents=True)
    (Path(args.out) / "count.json").write_text(json.dumps(list(range(1, config.to + 1))))
    result = {"run": args.out, "counted": config.to}
    return Trained(result, lambda: [f"counted to {config.to}; run: {args.out}"])


@pytest.fixture
def count_learner() -> Iterator[None]:
    command = Command("count to N (a toy)", "A toy learner registered by the tests.", (settings(CountConfig), Options(RunOutput)))
    register(TrainLearner("count", command, train_count, metric=("loss", "min", "last")))
    yield
    del LEARNERS["count"]


def test_a_registered_learner_is_a_train_command(count_learner: None, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    helps = {option: action.help for action in cli._subcommands(cli._subcommands(cli.make_parser())["train"])["count"]._actions for option in action.option_strings}
    assert helps["--to"] == "how far the toy learner counts (default: 3)"
    out = tmp_path / "counted"
    assert cli.main(["train", "count", "--to", "5", "--out", str(out), "--json"]) == 0
    assert json.loads(capsys.readouterr().out.splitlines()[-1]) == {"run": str(out), "counted": 5}
    assert json.loads((out / "count.json").read_text()) == [1, 2, 3, 4, 5]
    assert cli.main(["train", "count", "--out", str(tmp_path / "again")]) == 0
    assert capsys.readouterr().out == f"counted to 3; run: {tmp_path / 'again'}\n"


def test_a_sweep_takes_a_registered_learners_metric(count_learner: None) -> None:
    assert default_metric("train count", {}) == ("loss", "min", "last")
    assert "train count" in cli._train_commands() and "to" in cli._train_commands()["train count"]
    assert default_metric("train bc", {}) == ("validation_loss", "min", "best")
    assert default_metric("train nothing", {}) is None
