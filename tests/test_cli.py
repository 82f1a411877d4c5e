"""The command line contract: --help everywhere, --json as the last stdout line, one-line errors
with exit code 1 (2 for usage), no traceback, nothing half-written."""

from __future__ import annotations

import json
import subprocess
import sys
import time

import pytest
from support import DATASETS, REPO, run_cli, run_cli_many


def last_json(result: subprocess.CompletedProcess) -> dict:
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout.strip().splitlines()[-1])


def assert_one_line_error(result: subprocess.CompletedProcess, *fragments: str) -> None:
    assert result.returncode == 1, (result.returncode, result.stderr)
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
    assert "Traceback" not in result.stderr
    for fragment in fragments:
        assert fragment in lines[0], (fragment, lines[0])


@pytest.mark.parametrize("command", [[], ["record"], ["info"], ["train"], ["train", "ppo"], ["train", "pg"], ["eval"], ["eval", "policy"]])
def test_help(command: list[str]) -> None:
    result = run_cli(*command, "--help")
    assert result.returncode == 0 and "usage: imitation" in result.stdout


def test_help_and_info_start_fast_without_torch_or_lerobot() -> None:
    code = "import sys, cli, imitation.data.summary; cli.make_parser(); print('torch' in sys.modules, 'lerobot' in sys.modules)"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO)
    assert result.stdout.split() == ["False", "False"], result.stderr
    started = time.perf_counter()
    run_cli("--help")
    assert time.perf_counter() - started < 5


def test_usage_error_exits_2() -> None:
    result = run_cli("record", "--env")
    assert result.returncode == 2


def test_record_then_info_json(tmp_path) -> None:
    out = tmp_path / "pendulum.mcap"
    record = last_json(run_cli("record", "--env", "Pendulum-v1", "--expert", "scripted", "--episodes", "3", "--seed", "5", "--out", str(out), "--json"))
    assert record["episodes"] == 3 and record["mean_return"] > -400
    info = last_json(run_cli("info", str(out), "--json"))
    assert info["episodes"] == 3 and info["transitions"] == 600 and info["env_id"] == "Pendulum-v1"
    assert info["return"]["mean"] == pytest.approx(record["mean_return"])
    assert set(info["return"]) == set(info["length"]) == {"mean", "std", "min", "max"}
    assert info["length"] == {"mean": 200.0, "std": 0.0, "min": 200.0, "max": 200.0}
    assert info["observation_space"]["type"] == "Box" and info["action_space"]["shape"] == [1]
    assert info["format_version"] == 1 and info["damage"] is None and info["salvaged"] is None
    assert "/observation" in info["channels"] and "/episode" in info["channels"]


def test_same_seed_same_recording(tmp_path) -> None:
    for name in ("a", "b"):
        assert run_cli("record", "--env", "CartPole-v1", "--expert", "random", "--episodes", "4", "--seed", "9", "--out", str(tmp_path / f"{name}.mcap")).returncode == 0
    info_a = last_json(run_cli("info", str(tmp_path / "a.mcap"), "--json"))
    info_b = last_json(run_cli("info", str(tmp_path / "b.mcap"), "--json"))
    assert info_a["return"] == info_b["return"] and info_a["transitions"] == info_b["transitions"]


def test_info_human_readable() -> None:
    result = run_cli("info", str(DATASETS / "CartPole-v1.mcap"))
    assert result.returncode == 0
    assert "CartPole-v1" in result.stdout and "Discrete(2)" in result.stdout and "return:" in result.stdout


def test_unknown_env_id(tmp_path) -> None:
    result = run_cli("record", "--env", "NoSuchEnv-v0", "--out", str(tmp_path / "x.mcap"))
    assert_one_line_error(result, "NoSuchEnv-v0")
    assert list(tmp_path.iterdir()) == []


def test_unwritable_output(tmp_path) -> None:
    assert_one_line_error(run_cli("record", "--env", "CartPole-v1", "--out", str(tmp_path / "missing" / "x.mcap")), "missing/x.mcap", "cannot write")
    assert_one_line_error(run_cli("record", "--env", "CartPole-v1", "--out", str(tmp_path)), "is a directory")


def test_unknown_expert(tmp_path) -> None:
    assert_one_line_error(run_cli("record", "--env", "CartPole-v1", "--expert", "oracle", "--out", str(tmp_path / "x.mcap")), "oracle")
    assert_one_line_error(run_cli("record", "--env", "Acrobot-v1", "--expert", "scripted", "--out", str(tmp_path / "x.mcap")), "no scripted expert")
    assert list(tmp_path.iterdir()) == []


def test_info_on_bad_files(tmp_path) -> None:
    (tmp_path / "notes.mcap").write_text("not mcap at all")
    assert_one_line_error(run_cli("info", str(tmp_path / "notes.mcap")), "notes.mcap", "not an MCAP file")
    assert_one_line_error(run_cli("info", str(tmp_path / "absent.mcap")), "absent.mcap", "cannot open")


def test_info_reports_salvage_of_a_truncated_file(tmp_path) -> None:
    data = (DATASETS / "MountainCar-v0.mcap").read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    result = run_cli("info", str(cut), "--json")
    assert_one_line_error(result, "cut.mcap", "damaged", "complete episodes are readable")
    info = json.loads(result.stdout.strip().splitlines()[-1])
    assert 0 < info["salvaged"] == info["episodes"] < 50 and info["damage"]


@pytest.mark.parametrize(("flag", "value"), [("--entropy", "nan"), ("--l2", "inf"), ("--lr", "nan"), ("--validation", "inf")])
def test_non_finite_numbers_are_refused_where_they_enter(tmp_path, flag: str, value: str) -> None:
    result = run_cli("train", "bc", "--demos", str(DATASETS / "CartPole-v1.mcap"), flag, value, "--out", str(tmp_path / "r"))
    assert result.returncode == 2 and f"argument {flag}: expected a finite number, got {value!r}" in result.stderr
    assert not any(tmp_path.iterdir())


def test_seeds_every_generator_cannot_take_are_refused_where_they_enter(tmp_path) -> None:
    """numpy refuses a negative seed and torch one from 2^64 on, deep inside a job: the flag
    refuses both (and anything from 2^32 on, which leaves room for the seeds a job derives)."""
    demos = str(DATASETS / "CartPole-v1.mcap")
    commands = [
        ["record", "--env", "CartPole-v1", "--expert", "scripted", "--out", str(tmp_path / "r.mcap")],
        ["train", "bc", "--demos", demos, "--out", str(tmp_path / "bc")],
        ["train", "ppo", "--env", "CartPole-v1", "--out", str(tmp_path / "ppo")],
    ]
    cases = [(command, seed) for command in commands for seed in ("-1", str(2**70), str(2**32))]
    for (command, seed), result in zip(cases, run_cli_many([[*command, "--seed", seed] for command, seed in cases])):
        assert result.returncode == 2 and "Traceback" not in result.stderr, result.stderr
        assert f"argument --seed: must be a whole number from 0 to 4294967295, got {seed}" in result.stderr, result.stderr
    assert not any(tmp_path.iterdir())


def test_bc_on_demos_a_policy_cannot_take_names_the_file(tmp_path) -> None:
    import gymnasium as gym
    import numpy as np

    from imitation.data.mcap.writer import write_episodes
    from imitation.data.types import Episode

    space = gym.spaces.Dict({"a": gym.spaces.Box(-1, 1, (2,), np.float32)})  # Dict observations are read; Dict actions are not
    episode = Episode(observations=np.zeros((4, 2), np.float32), actions={"a": np.zeros((3, 2), np.float32)}, rewards=np.zeros(3), truncated=True)
    demos = write_episodes(tmp_path / "dict.mcap", [episode], env_id="", observation_space=space["a"], action_space=space)
    assert_one_line_error(run_cli("train", "bc", "--demos", str(demos), "--out", str(tmp_path / "r")), f"{demos}: policies take Discrete, MultiDiscrete or Box actions")


def test_train_bc_help_names_the_configs_own_defaults() -> None:
    """`train bc` flags have no argparse defaults (an absent flag leaves BCConfig's), so the help
    text is the one place a default is repeated: it must say what BCConfig does."""
    import dataclasses
    import re

    from cli import make_parser
    from imitation.algorithms.bc import BCConfig
    from imitation.flags import flag_name, flagged

    parser = make_parser()
    bc = parser._subparsers._group_actions[0].choices["train"]._subparsers._group_actions[0].choices["bc"]
    helps = {option: action.help for action in bc._actions for option in action.option_strings}
    defaults = {f.name: f.default if f.default is not dataclasses.MISSING else f.default_factory() for f in dataclasses.fields(BCConfig)}
    for field, flag in ((field.name, flag_name(field)) for field in flagged(BCConfig)):
        shown = re.search(r"\(default: ([^):]+)", helps[flag])
        assert shown is not None, flag
        value = defaults[field]
        if value is None:  # decided when the run starts (e.g. from the demos): the help says how, in words
            assert not shown[1].startswith("None"), flag
            continue
        if isinstance(value, bool):
            expected = "on" if value else "off"
        else:
            expected = ",".join(map(str, value)) if isinstance(value, list) else str(value)
        assert shown[1] == expected, (flag, shown[1], expected)
        assert bc.get_default(flag.lstrip("-").replace("-", "_")) is None, flag
