"""Crash safety of real processes: Ctrl-C during `train ppo`, `train bc`, `train dagger` and
`train irl` (gcl, and tabular mce) keeps the last checkpoint, which loads, which `--resume` with
other settings refuses and which `--resume` continues to the requested total; `kill -9` during
DAgger leaves every finished round readable, and during `convert` every finished episode (each is
flushed as its own chunk; tests/data/test_store.py checks that episode by episode), with nothing
under a final name that is not whole.
(`kill -9` and Ctrl-C during `record`: tests/data/test_recorder.py.)"""

from __future__ import annotations

import csv
import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from support import DATASETS, REPO, run_cli_many
from test_cli import assert_one_line_error, last_json

import imitation.jobs.dagger
from imitation.algorithms.bc import BCConfig
from imitation.algorithms.dagger import DAggerConfig
from imitation.checkpoints import unprefixed
from imitation.data.convert.npz import npz_to_episodes
from imitation.data.mcap.reader import DemoFile
from imitation.jobs.dagger import dagger_job
from imitation.jobs.loop import TrainingInterrupted
from imitation.policies import ActorCritic, PolicyConfig
from imitation.rewards import RewardConfig, RewardNet, load_reward
from imitation.runs import read_checkpoint


def start(*args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, str(REPO / "cli.py"), *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO)


def wait_for(path: Path, process: subprocess.Popen, timeout: float = 120) -> None:
    deadline = time.monotonic() + timeout
    while not path.exists():
        assert process.poll() is None, f"the process ended before {path} appeared: {process.communicate()[1][-2000:]}"
        assert time.monotonic() < deadline, f"{path} did not appear within {timeout} s"
        time.sleep(0.05)


def interrupt_after_first_checkpoint(*args: str, out: Path) -> str:
    """Run `imitation ARGS`, press Ctrl-C once a checkpoint exists; the last stderr line."""
    process = start(*args)
    try:
        wait_for(out.with_name(out.name + ".partial") / "checkpoint" / "state.json", process)
        process.send_signal(signal.SIGINT)
        _, stderr = process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 130, stderr
    assert "Traceback" not in stderr
    return [line for line in stderr.splitlines() if line.strip()][-1]


def changed(args: list[str], flag: str, value: str) -> list[str]:
    """`args` with `flag`'s value replaced: the same command with one setting changed."""
    at = args.index(flag) + 1
    return [*args[:at], value, *args[at + 1 :]]


def progress_rows(run: Path) -> list[dict[str, float]]:
    with open(run / "progress.csv") as stream:
        return [{key: float(value) for key, value in row.items()} for row in csv.DictReader(stream)]


def test_ctrl_c_during_train_ppo_keeps_a_checkpoint_that_resume_finishes(tmp_path: Path) -> None:
    out = tmp_path / "ppo"
    partial = tmp_path / "ppo.partial"
    # CartPole's defaults: 8 envs × 32 steps = 256 steps per update, 50 updates, a checkpoint every 5.
    args = ["train", "ppo", "--env", "CartPole-v1", "--steps", "12800", "--seed", "3", "--quiet", "--out", str(out)]
    message = interrupt_after_first_checkpoint(*args, out=out)
    assert message.startswith("interrupted: PPO stopped after update ") and f"of 12800; its checkpoint is in {partial}" in message
    assert message.endswith("run the same command with --resume to continue")
    assert not out.exists() and partial.is_dir()

    # The checkpoint loads: a whole policy, and the counters of the update it was taken after.
    tensors, state = read_checkpoint(partial)
    trainer = state["trainer"]
    stopped_at = int(message.split("after update ")[1].split("/")[0])
    assert trainer["update"] == stopped_at and trainer["global_step"] == 256 * stopped_at < 12800
    assert len(state["history"]) == stopped_at  # the rows are the run directory's, saved beside the trainer's state
    policy = ActorCritic(PolicyConfig.from_json(trainer["policy"]))
    policy.load_state_dict({name.removeprefix("policy."): t for name, t in tensors.items() if name.startswith("policy.")})
    assert torch.isfinite(policy.value(policy.encode(torch.zeros(1, 4)))).all()

    resumed, evaluation = run_cli_many([[*args, "--resume", "--json"], ["eval", "policy", str(out), "--env", "CartPole-v1", "--episodes", "2", "--json"]])
    result = last_json(resumed)
    assert result["steps"] == 12800, "a resumed run's step count is the requested total"
    assert not partial.exists() and (out / "model.safetensors").is_file()
    rows = progress_rows(out)
    assert [row["step"] for row in rows] == [256.0 * (i + 1) for i in range(50)], "every update logged once, in order"
    assert last_json(evaluation)["episodes"] == 2


@pytest.mark.parametrize(
    ("command", "name", "unit", "count"),
    [
        (["pg", "--env", "CartPole-v1", "--steps", "16000", "--batch-steps", "500"], "policy gradient", "batch", "batches"),
        (["cem", "--env", "CartPole-v1", "--steps", "60000"], "CEM", "generation", "generations"),
    ],
)
def test_ctrl_c_during_the_notes_learners_keeps_a_checkpoint_that_resume_finishes(
    tmp_path: Path, command: list[str], name: str, unit: str, count: str
) -> None:
    out = tmp_path / "run"
    args = ["train", *command, "--seed", "3", "--quiet", "--out", str(out)]
    message = interrupt_after_first_checkpoint(*args, out=out)
    assert message.startswith(f"interrupted: {name} stopped after {unit} ") and "--resume to continue" in message
    stopped_at = int(message.split(f"after {unit} ")[1].split(",")[0])
    assert len(read_checkpoint(out.with_name("run.partial"))[1]["history"]) == stopped_at

    resumed, evaluation = run_cli_many([[*args, "--resume", "--json"], ["eval", "policy", str(out), "--env", "CartPole-v1", "--episodes", "2", "--json"]])
    result = last_json(resumed)
    rows = progress_rows(out)
    assert len(rows) == result[count] > stopped_at, "every step logged once: those before the interruption and after"
    steps = [row["step"] for row in rows]
    assert steps == sorted(steps) and len(set(steps)) == len(steps)
    assert last_json(evaluation)["episodes"] == 2


def test_ctrl_c_during_train_bc_keeps_a_checkpoint_that_resume_finishes(tmp_path: Path) -> None:
    out = tmp_path / "bc"
    partial = tmp_path / "bc.partial"
    args = ["train", "bc", "--demos", str(DATASETS / "CartPole-v1.mcap"), "--env", "CartPole-v1", "--epochs", "20", "--patience", "20", "--hidden", "32,32", "--quiet", "--out", str(out)]
    message = interrupt_after_first_checkpoint(*args, out=out)
    # at the next minibatch, within an epoch (or at its end)
    stopped = re.match(r"interrupted: BC stopped after (?:batch \d+ of \d+ in epoch (\d+)|epoch (\d+)) of 20; its checkpoint is in ", message)
    assert stopped is not None and f"its checkpoint is in {partial}" in message, message
    finished = int(stopped[1]) - 1 if stopped[1] else int(stopped[2])
    tensors, state = read_checkpoint(partial)
    assert state["trainer"]["epoch"] == finished + 1 and len(state["history"]) == finished
    config = json.loads((partial / "config.json").read_text())
    policy = ActorCritic(PolicyConfig.from_json(config["policy"]))
    policy.load_state_dict({name.removeprefix("policy."): t for name, t in tensors.items() if name.startswith("policy.")})

    resumed, evaluation = run_cli_many([[*args, "--resume", "--json"], ["eval", "policy", str(out), "--env", "CartPole-v1", "--episodes", "2", "--json"]])
    result = last_json(resumed)
    assert result["epochs"] == 20 and not partial.exists()
    assert [row["epoch"] for row in progress_rows(out)] == [float(e) for e in range(1, 21)]
    assert last_json(evaluation)["episodes"] == 2


def test_resume_refuses_what_it_cannot_continue(tmp_path: Path) -> None:
    from imitation.algorithms.ppo import PPOConfig
    from imitation.jobs.presets import ppo_settings
    from imitation.runs import RunWriter

    # An interrupted 4096-step run with a checkpoint, and one stopped before its first checkpoint.
    config = PPOConfig(env_id="CartPole-v1", total_steps=4096, **ppo_settings("CartPole-v1"))
    for name, checkpoint in (("checkpointed", True), ("early", False)):
        with pytest.raises(KeyboardInterrupt):
            with RunWriter(tmp_path / name, config={"kind": "ppo", "env_id": "CartPole-v1", "creator": "x", "ppo": vars(config)}, tensorboard=False) as run:
                if checkpoint:
                    run.save_checkpoint({"x": torch.zeros(1)}, {"update": 1})
                raise KeyboardInterrupt
    assert (tmp_path / "checkpointed.partial").is_dir() and not (tmp_path / "early.partial").exists()
    (tmp_path / "early.partial").mkdir()  # as a kill -9 before the first checkpoint leaves it

    def ppo(name: str, steps: str) -> list[str]:
        return ["train", "ppo", "--env", "CartPole-v1", "--steps", steps, "--quiet", "--out", str(tmp_path / name), "--resume"]

    never, early, other_settings = run_cli_many([ppo("never", "4096"), ppo("early", "4096"), ppo("checkpointed", "8192")])
    assert_one_line_error(never, f"--resume: {tmp_path / 'never.partial'} does not exist, so there is no interrupted run to continue")
    assert_one_line_error(early, f"{tmp_path / 'early.partial'}: holds no checkpoint")
    assert_one_line_error(other_settings, f"--resume: {tmp_path / 'checkpointed.partial'} was started with other settings (ppo.total_steps: 4096 there, 8192 now)")
    assert (tmp_path / "checkpointed.partial" / "checkpoint").is_dir(), "a refused --resume leaves the interrupted run alone"


def test_kill_9_during_dagger_leaves_every_finished_round_readable(tmp_path: Path) -> None:
    out = tmp_path / "dagger"
    rounds = tmp_path / "dagger.partial" / "rounds"
    process = start("train", "dagger", "--env", "CartPole-v1", "--expert", "scripted", "--rounds", "30", "--episodes-per-round", "2",
                    "--epochs", "3", "--hidden", "16", "--quiet", "--out", str(out))
    try:
        wait_for(rounds / "round-03.mcap", process)
    finally:
        os.kill(process.pid, signal.SIGKILL)
        process.wait()
    assert not out.exists(), "the final name appears only for a finished run"
    finished = sorted(rounds.glob("round-*.mcap"))
    assert len(finished) >= 3
    assert [path.name for path in finished] == [f"round-{i:02d}.mcap" for i in range(1, len(finished) + 1)]
    for path in finished:
        demo = DemoFile(path, verify=True)
        assert demo.damage is None and len(demo) == 2 and demo.episodes[0].metadata["round"] == int(path.stem[-2:])
        assert all(len(episode) > 0 for episode in demo)
    leftovers = {path.name for path in rounds.iterdir()} - {path.name for path in finished}
    assert all(name.endswith(".mcap.partial") for name in leftovers), leftovers


def test_ctrl_c_during_train_dagger_keeps_a_checkpoint_that_resume_finishes_with_the_recorded_rounds(tmp_path: Path) -> None:
    out = tmp_path / "dagger"
    partial = tmp_path / "dagger.partial"
    # 12 rounds: a checkpoint after each; Ctrl-C stops after the round it lands in. Rounds this small
    # take a fraction of a second, so fewer left a loaded machine time to finish them all first.
    args = ["train", "dagger", "--env", "CartPole-v1", "--expert", "scripted", "--rounds", "12", "--episodes-per-round", "2", "--epochs", "3",
            "--hidden", "16", "--quiet", "--out", str(out)]
    message = interrupt_after_first_checkpoint(*args, out=out)
    assert message.startswith("interrupted: DAgger stopped after round ") and f"of 12; its checkpoint is in {partial}" in message
    assert message.endswith("run the same command with --resume to continue")
    assert not out.exists() and partial.is_dir()
    stopped_at = int(message.split("after round ")[1].split(" ")[0])
    assert 1 <= stopped_at < 12

    tensors, state = read_checkpoint(partial)
    trainer = state["trainer"]
    recorded = [f"round-{i:02d}.mcap" for i in range(1, stopped_at + 1)]
    assert trainer["round"] == stopped_at + 1 and trainer["round_files"] == recorded and len(state["history"]) == stopped_at
    policy = ActorCritic(PolicyConfig.from_json(json.loads((partial / "config.json").read_text())["policy"]))
    policy.load_state_dict(unprefixed("policy", tensors))
    files = {name: os.stat(partial / "rounds" / name) for name in recorded}

    other, resumed, evaluation = run_cli_many([
        [*changed(args, "--episodes-per-round", "3"), "--resume"], [*args, "--resume", "--json"],
        ["eval", "policy", str(out), "--env", "CartPole-v1", "--episodes", "2", "--json"],
    ])
    assert_one_line_error(other, f"--resume: {partial} was started with other settings (dagger.episodes_per_round: 2 there, 3 now)")
    result = last_json(resumed)
    assert result["rounds"] == 12 and not partial.exists()
    assert [row["round"] for row in progress_rows(out)] == [float(i) for i in range(1, 13)]
    assert [Path(path).name for path in result["round_files"]] == [f"round-{i:02d}.mcap" for i in range(1, 13)]
    for name, before in files.items():  # reused, not recorded again
        after = os.stat(out / "rounds" / name)
        assert (after.st_ino, after.st_mtime_ns) == (before.st_ino, before.st_mtime_ns), name
    assert last_json(evaluation)["episodes"] == 2


def test_ctrl_c_after_the_last_dagger_round_keeps_the_trained_checkpoint_and_resume_only_evaluates(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    out = tmp_path / "dagger"
    config = DAggerConfig(rounds=2, episodes_per_round=1, seed=0, bc=BCConfig(epochs=2, hidden_sizes=[16], seed=0, device="cpu"))
    evaluation = imitation.jobs.dagger.final_evaluation

    def ctrl_c(*_: object) -> None:  # what Python's default SIGINT handler does, in the final evaluation
        raise KeyboardInterrupt

    monkeypatch.setattr(imitation.jobs.dagger, "final_evaluation", ctrl_c)
    with pytest.raises(TrainingInterrupted, match=r"stopped before the run was written; its last checkpoint is in .*dagger\.partial: run the same"):
        dagger_job("CartPole-v1", "scripted", config, out, progress=False)
    tensors, state = read_checkpoint(tmp_path / "dagger.partial")
    assert state["trainer"]["round"] == 3 and len(state["history"]) == 2, "the checkpoint after the last round"
    files = {name: os.stat(tmp_path / "dagger.partial" / "rounds" / name) for name in ("round-01.mcap", "round-02.mcap")}

    monkeypatch.setattr(imitation.jobs.dagger, "final_evaluation", evaluation)
    result = dagger_job("CartPole-v1", "scripted", config, out, progress=False, resume=True)
    assert result["rounds"] == 2 and result["eval"]["episodes"] > 0
    for name, before in files.items():  # nothing trained or recorded again
        after = os.stat(out / "rounds" / name)
        assert (after.st_ino, after.st_mtime_ns) == (before.st_ino, before.st_mtime_ns), name


def test_ctrl_c_during_train_irl_gcl_keeps_a_checkpoint_with_the_reward_learner_that_resume_finishes(tmp_path: Path) -> None:
    out = tmp_path / "gcl"
    partial = tmp_path / "gcl.partial"
    env_id = "imitation/CartPoleFixedHorizon-v0"
    # The env's defaults: 8 envs × 32 steps = 256 steps per update, 20 updates, a checkpoint every 2.
    args = ["train", "irl", "--method", "gcl", "--env", env_id, "--demos", str(DATASETS / "CartPoleFixedHorizon-v0.mcap"), "--steps", "5120",
            "--hidden", "16", "--quiet", "--out", str(out)]
    message = interrupt_after_first_checkpoint(*args, out=out)
    assert message.startswith("interrupted: PPO stopped after update ") and f"of 5120; its checkpoint is in {partial}" in message
    assert not out.exists() and partial.is_dir()
    stopped_at = int(message.split("after update ")[1].split("/")[0])

    # PPO's checkpoint holds the reward learner: r_θ, its optimiser, every rollout in the pool, its rows.
    tensors, state = read_checkpoint(partial)
    trainer = state["trainer"]
    assert trainer["update"] == stopped_at and trainer["learner"]["learned"] == stopped_at
    learner = unprefixed("learner", tensors)
    assert learner["pool.log_mass"].shape == (256 * stopped_at,) and "sampler.0.action_head.weight" in learner and "generator" in learner
    assert any(name.startswith("optimizer.") for name in learner)
    reward = RewardNet(RewardConfig.from_json(json.loads((partial / "config.json").read_text())["reward"]))
    reward.load_state_dict(unprefixed("reward", learner))
    assert torch.isfinite(reward(torch.zeros(3, 5), torch.zeros(3, dtype=torch.int64), torch.zeros(3, 5))).all()

    other, resumed, evaluation = run_cli_many([
        [*changed(args, "--steps", "10240"), "--resume"], [*args, "--resume", "--json"],
        ["eval", "policy", str(out), "--env", env_id, "--episodes", "2", "--json"],
    ])
    assert_one_line_error(other, f"--resume: {partial} was started with other settings (ppo.total_steps: 5120 there, 10240 now)")
    result = last_json(resumed)
    assert result["steps"] == 5120 and not partial.exists()
    rows = progress_rows(out)
    assert [row["step"] for row in rows] == [256.0 * (i + 1) for i in range(20)] and all(np.isfinite(row["reward_loss"]) for row in rows)
    assert torch.isfinite(load_reward(out)(torch.zeros(3, 5), torch.zeros(3, dtype=torch.int64), torch.zeros(3, 5))).all()
    assert last_json(evaluation)["episodes"] == 2


def test_ctrl_c_during_tabular_train_irl_keeps_a_checkpoint_that_resume_finishes(tmp_path: Path) -> None:
    out = tmp_path / "mce"
    partial = tmp_path / "mce.partial"
    env_id = "imitation/GridWorld8x8-v0"
    # Tolerance 0: all 1000 iterations run (~1 ms each), a checkpoint every 100.
    args = ["train", "irl", "--method", "mce", "--env", env_id, "--demos", str(DATASETS / "GridWorld8x8-v0.mcap"), "--iterations", "1000",
            "--tolerance", "0", "--quiet", "--out", str(out)]
    message = interrupt_after_first_checkpoint(*args, out=out)
    assert message.startswith("interrupted: mce IRL stopped after iteration ") and f"of 1000; its checkpoint is in {partial}" in message
    assert not out.exists() and partial.is_dir()
    stopped_at = int(message.split("after iteration ")[1].split(" ")[0])

    tensors, state = read_checkpoint(partial)
    assert state["trainer"]["iteration"] == stopped_at + 1 and len(state["history"]) == stopped_at
    reward = RewardNet(RewardConfig.from_json(json.loads((partial / "config.json").read_text())["reward"]))
    reward.load_state_dict(unprefixed("reward", tensors))

    other, resumed, evaluation = run_cli_many([
        [*changed(args, "--iterations", "2000"), "--resume"], [*args, "--resume", "--json"],
        ["eval", "reward", str(out), "--env", env_id, "--retrain-steps", "0", "--quiet", "--json"],
    ])
    assert_one_line_error(other, f"--resume: {partial} was started with other settings (irl.iterations: 1000 there, 2000 now)")
    result = last_json(resumed)
    assert result["iterations"] == 1000 and not partial.exists()
    assert [row["iteration"] for row in progress_rows(out)] == [float(i) for i in range(1, 1001)]
    assert "epic" in last_json(evaluation)


def test_ctrl_c_during_train_irl_apprenticeship_keeps_a_checkpoint_that_resume_finishes(tmp_path: Path) -> None:
    """The PPO solver on fixed-horizon CartPole, a checkpoint after every iteration (each is a
    PPO run of 2048 steps): Ctrl-C after the first leaves the iterations so far, and --resume
    finishes the run with each iteration logged once and a reward `eval reward` reads."""
    out = tmp_path / "app"
    partial = tmp_path / "app.partial"
    env_id = "imitation/CartPoleFixedHorizon-v0"
    args = ["train", "irl", "--method", "apprenticeship", "--env", env_id, "--demos", str(DATASETS / "CartPoleFixedHorizon-v0.mcap"),
            "--iterations", "4", "--steps", "2048", "--episodes", "2", "--tolerance", "0", "--seed", "3", "--quiet", "--out", str(out)]
    message = interrupt_after_first_checkpoint(*args, out=out)
    assert message.startswith("interrupted: apprenticeship learning stopped after iteration ") and f"of 4; its checkpoint is in {partial}" in message
    stopped_at = int(message.split("after iteration ")[1].split(" ")[0])
    assert 1 <= stopped_at < 4 and len(read_checkpoint(partial)[1]["history"]) == stopped_at

    resumed, evaluation = run_cli_many([
        [*args, "--resume", "--json"],
        ["eval", "reward", str(out), "--env", env_id, "--retrain-steps", "0", "--quiet", "--json"],
    ])
    assert last_json(resumed)["iterations"] == 4 and not partial.exists()
    assert [row["iteration"] for row in progress_rows(out)] == [1.0, 2.0, 3.0, 4.0]
    assert "epic" in last_json(evaluation)


def test_kill_9_during_convert_leaves_no_final_file_and_a_partial_one_whose_complete_episodes_read_back(tmp_path: Path) -> None:
    # 30,000 short episodes: writing them takes seconds, each flushed as its own chunk.
    episodes, length = 30_000, 10
    rows = episodes * length
    rng = np.random.default_rng(0)
    source = tmp_path / "rollouts.npz"
    np.savez(source, obs=rng.normal(size=(rows, 4)).astype(np.float32), actions=rng.integers(0, 2, (rows, 1)), rewards=rng.normal(size=rows),
             episode_starts=np.arange(rows) % length == 0)
    out = tmp_path / "converted.mcap"
    partial = tmp_path / "converted.mcap.partial"
    process = start("convert", str(source), "--out", str(out), "--quiet")
    try:
        deadline = time.monotonic() + 120
        while not (partial.exists() and partial.stat().st_size > 2_000_000):  # past the first chunks
            assert process.poll() is None, f"convert ended before it was killed: {process.communicate()[1][-2000:]}"
            assert time.monotonic() < deadline
            time.sleep(0.01)
    finally:
        os.kill(process.pid, signal.SIGKILL)
        process.wait()
    assert not out.exists(), "the final name appears only for a finished file"
    demo = DemoFile(partial, salvage=True, verify=True)
    assert demo.damage is not None and 0 < len(demo) < episodes
    expected = npz_to_episodes(source).episodes
    for k, episode in enumerate(demo):
        np.testing.assert_array_equal(episode.observations, expected[k].observations)
        np.testing.assert_array_equal(episode.actions, expected[k].actions)
        np.testing.assert_array_equal(episode.rewards, expected[k].rewards)


def test_resume_refuses_a_checkpoint_whose_counter_was_tampered_with(tmp_path: Path) -> None:
    out = tmp_path / "bc"
    args = ["train", "bc", "--demos", str(DATASETS / "CartPole-v1.mcap"), "--env", "CartPole-v1", "--epochs", "50", "--hidden", "16", "--quiet",
            "--out", str(out)]
    interrupt_after_first_checkpoint(*args, out=out)
    state_file = tmp_path / "bc.partial" / "checkpoint" / "state.json"
    state = json.loads(state_file.read_text())
    state["trainer"]["epoch"] = -10**12
    state_file.write_text(json.dumps(state))
    started = time.monotonic()
    result = run_cli_many([[*args, "--resume"]])[0]
    assert_one_line_error(result, "the checkpoint's next epoch is -1000000000000, outside 1..51 for this run")
    assert time.monotonic() - started < 60


CARTPOLE_DEMOS = str(DATASETS / "CartPole-v1.mcap")
FIXED_DEMOS = str(DATASETS / "CartPoleFixedHorizon-v0.mcap")
GRID_DEMOS = str(DATASETS / "GridWorld8x8-v0.mcap")
# Every learner whose run ends in a final evaluation or records what it learnt in config.json
# after training, at sizes of seconds.
LEARNERS = {
    "ppo": ["train", "ppo", "--env", "CartPole-v1", "--steps", "1024"],
    "pg": ["train", "pg", "--env", "CartPole-v1", "--steps", "2000"],
    "cem": ["train", "cem", "--env", "CartPole-v1", "--population", "3", "--steps", "4000"],
    "bc": ["train", "bc", "--demos", CARTPOLE_DEMOS, "--env", "CartPole-v1", "--epochs", "2"],
    "gail": ["train", "irl", "--method", "gail", "--env", "imitation/CartPoleFixedHorizon-v0", "--demos", FIXED_DEMOS, "--steps", "2048"],
    "apprenticeship": ["train", "irl", "--method", "apprenticeship", "--env", "imitation/GridWorld8x8-v0", "--demos", GRID_DEMOS,
                       "--iterations", "2"],
}


@pytest.mark.parametrize("learner", list(LEARNERS))
def test_ctrl_c_at_the_end_of_any_learner_resumes_to_the_result_of_an_uninterrupted_run(
    learner: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    """Ctrl-C once training is over (after config.json gained the policy, or in the final
    evaluation: where a user waits longest for nothing visible) keeps a checkpoint that --resume
    finishes, with the weights and evaluation of a run that was never stopped."""
    import cli
    import imitation.runs
    from imitation.jobs import bc, irl, pg, ppo, search

    argv = [*LEARNERS[learner], "--seed", "3", "--quiet", "--json"]
    assert cli.main([*argv, "--out", str(tmp_path / "whole")]) == 0
    whole = last_json_of(capsys)

    update_config, stopped = imitation.runs.RunWriter.update_config, []

    def ctrl_c(*_: object, **__: object) -> None:  # what Python's default SIGINT handler does
        stopped.append(True)
        raise KeyboardInterrupt

    def updated_then_ctrl_c(self: object, **entries: object) -> None:
        update_config(self, **entries)
        ctrl_c()

    for module in (ppo, pg, search, bc, irl):
        monkeypatch.setattr(module, "final_evaluation", ctrl_c)
    monkeypatch.setattr(imitation.runs.RunWriter, "update_config", updated_then_ctrl_c)
    out = tmp_path / "stopped"
    assert cli.main([*argv, "--out", str(out)]) == 130 and stopped
    assert "its last checkpoint is in" in capsys.readouterr().err
    monkeypatch.undo()
    assert cli.main([*argv, "--out", str(out), "--resume"]) == 0, capsys.readouterr().err
    resumed = last_json_of(capsys)
    assert (out / "model.safetensors").read_bytes() == (tmp_path / "whole" / "model.safetensors").read_bytes()
    assert resumed.get("eval") == whole.get("eval") and resumed.get("mixture_return") == whole.get("mixture_return")


def last_json_of(capsys: pytest.CaptureFixture) -> dict:
    return json.loads(capsys.readouterr().out.strip().splitlines()[-1])
