"""`train bc` and `train dagger` from the command line, and their bad inputs."""

from __future__ import annotations

import json

import gymnasium as gym
from support import DATASETS, run_cli
from test_cli import assert_one_line_error, last_json

from imitation.data.mcap.reader import DemoFile
from imitation.data.mcap.writer import DemoWriter


def test_train_bc_then_eval_and_record(tmp_path) -> None:
    out = tmp_path / "bc"
    result = last_json(run_cli("train", "bc", "--demos", str(DATASETS / "CartPole-v1.mcap"), "--env", "CartPole-v1",
                               "--epochs", "20", "--hidden", "64,64", "--out", str(out), "--json", timeout=300))
    assert result["epochs"] <= 20 and result["train_transitions"] + result["validation_transitions"] == 12500
    assert {"config.json", "model.safetensors", "metrics.json", "progress.csv", "loss_curve.png", "return_curve.png"} <= {p.name for p in out.iterdir()}
    header = (out / "progress.csv").read_text().splitlines()[0].split(",")
    assert {"epoch", "train_loss", "validation_loss", "return"} <= set(header)
    config = json.loads((out / "config.json").read_text())
    assert config["kind"] == "bc" and set(config["split"]["validation_episodes"]).isdisjoint(config["split"]["train_episodes"])
    evaluated = last_json(run_cli("eval", "policy", str(out), "--env", "CartPole-v1", "--episodes", "3", "--json"))
    assert evaluated["mean_return"] >= 400
    recorded = tmp_path / "from_bc.mcap"
    assert run_cli("record", "--env", "CartPole-v1", "--expert", str(out), "--episodes", "1", "--out", str(recorded)).returncode == 0
    assert len(DemoFile(recorded)) == 1


def test_bc_on_several_demo_files(tmp_path) -> None:
    first, second = tmp_path / "a.mcap", tmp_path / "b.mcap"
    for path, seed in ((first, "0"), (second, "50")):
        assert run_cli("record", "--env", "CartPole-v1", "--episodes", "2", "--seed", seed, "--out", str(path)).returncode == 0
    result = last_json(run_cli("train", "bc", "--demos", str(first), str(second), "--env", "CartPole-v1", "--epochs", "3",
                               "--hidden", "16", "--validation", "0.25", "--out", str(tmp_path / "bc"), "--json", timeout=300))
    assert result["train_transitions"] + result["validation_transitions"] == 2000


def test_bc_bad_demos(tmp_path) -> None:
    assert_one_line_error(
        run_cli("train", "bc", "--demos", str(DATASETS / "CartPole-v1.mcap"), "--env", "Pendulum-v1", "--out", str(tmp_path / "r")),
        "CartPole-v1.mcap", "observation space", "does not match",
    )
    empty = tmp_path / "empty.mcap"
    env = gym.make("CartPole-v1")
    DemoWriter(empty, env_id="CartPole-v1", observation_space=env.observation_space, action_space=env.action_space).close()
    assert_one_line_error(run_cli("train", "bc", "--demos", str(empty), "--env", "CartPole-v1", "--out", str(tmp_path / "r")), "empty.mcap", "no transitions")
    cut = tmp_path / "cut.mcap"
    data = (DATASETS / "CartPole-v1.mcap").read_bytes()
    cut.write_bytes(data[: len(data) // 3])
    assert_one_line_error(run_cli("train", "bc", "--demos", str(cut), "--env", "CartPole-v1", "--out", str(tmp_path / "r")), "cut.mcap", "damaged or unfinished")
    assert_one_line_error(run_cli("train", "bc", "--demos", str(DATASETS / "CartPole-v1.mcap"), "--env", "CartPole-v1", "--loss", "mse", "--out", str(tmp_path / "r")), "mse")
    assert not list(tmp_path.glob("r*"))


def test_train_dagger_writes_its_rounds(tmp_path) -> None:
    out = tmp_path / "dagger"
    result = last_json(run_cli("train", "dagger", "--env", "CartPole-v1", "--expert", "scripted", "--rounds", "2", "--episodes-per-round", "2",
                               "--epochs", "10", "--hidden", "32,32", "--out", str(out), "--json", timeout=300))
    assert result["rounds"] == 2 and len(result["round_returns"]) == 2
    rounds = sorted((out / "rounds").glob("round-*.mcap"))
    assert [p.name for p in rounds] == ["round-01.mcap", "round-02.mcap"] and [str(p) for p in rounds] == result["round_files"]
    assert result["expert_labels"] == sum(DemoFile(p).num_transitions for p in rounds)
    assert "return" in (out / "progress.csv").read_text().splitlines()[0]


def test_dagger_bad_experts(tmp_path, testdata) -> None:
    out = str(tmp_path / "r")
    assert_one_line_error(run_cli("train", "dagger", "--env", "CartPole-v1", "--expert", "oracle", "--out", out), "oracle")
    assert_one_line_error(run_cli("train", "dagger", "--env", "Acrobot-v1", "--expert", "scripted", "--out", out), "no scripted expert")
    zip_path = testdata / "experts" / "sb3_ppo_cartpole" / "CartPole-v1.zip"
    # A discrete (CartPole) expert cannot drive a continuous env.
    assert_one_line_error(run_cli("train", "dagger", "--env", "Pendulum-v1", "--expert", f"sb3:{zip_path}", "--out", out), "does not match")
    assert_one_line_error(run_cli("train", "dagger", "--env", "CartPole-v1", "--expert", f"sb3:{tmp_path / 'missing.zip'}", "--out", out), "missing.zip")
    assert not (tmp_path / "r").exists()
