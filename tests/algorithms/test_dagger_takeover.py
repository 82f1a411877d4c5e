"""Take-over DAgger (HG-DAgger) with the scripted stand-in for a person, the intervention channels
of the round files, and what a kill or Ctrl-C in the middle of a round keeps."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from support import REPO, run_cli, run_cli_many
from test_cli import assert_one_line_error, last_json

from imitation.algorithms.bc import BCConfig, policy_options
from imitation.algorithms.dagger import DAgger, DAggerConfig, collect_round, run_episode
from imitation.data.dataset import DemoDataset
from imitation.data.loader import human_steps
from imitation.data.mcap.reader import DemoFile, salvageable_episodes
from imitation.data.mcap.writer import write_episodes
from imitation.data.types import Episode, Interventions
from imitation.errors import DemoFileError, ImitationError
from imitation.experts.scripted import cartpole
from imitation.experts.standin import StandIn
from imitation.jobs.loop import run
from imitation.policies import make_policy

BOX = gym.spaces.Box(-np.inf, np.inf, (4,), np.float32)


def test_the_standin_engages_past_0_1_rad_and_releases_below_0_02() -> None:
    standin = StandIn("CartPole-v1")
    engaged = []
    for angle in (0.05, 0.1, 0.11, 0.05, 0.02, 0.019, 0.05, -0.12, -0.03, -0.01):
        action = standin(np.array([0.0, 0.0, angle, 0.0]))
        engaged.append(standin.engaged)
        assert action == cartpole(np.array([0.0, 0.0, angle, 0.0]))
    assert engaged == [False, False, True, True, True, False, False, True, True, False]
    with pytest.raises(ImitationError, match="--expert standin has no take-over condition for Pendulum-v1"):
        StandIn("Pendulum-v1")
    with pytest.raises(ImitationError, match=r"the release threshold 0.2 must lie in \[0, engage = 0.1\]"):
        StandIn("CartPole-v1", release=0.2)


def test_a_takeover_episode_executes_the_learner_until_the_standin_engages_and_records_who_drove() -> None:
    """The learner always pushes left; the stand-in steps in once the pole leans past 0.1 rad and
    hands back below 0.02. Executed actions are the learner's where it drove and the stand-in's
    where it did; the stored actions are the executed ones; hand-overs alternate, starting with
    one to the person."""
    env = gym.make("CartPole-v1")
    standin = StandIn("CartPole-v1")
    episode = run_episode(env, lambda observation: 0, standin, mode="takeover", seed=3, rng=np.random.default_rng(0), metadata={})
    interventions = episode.interventions
    assert interventions is not None and 0 < interventions.human.sum() < len(episode)
    angles = np.abs(episode.observations[:-1, 2])
    state = False
    for t, angle in enumerate(angles):
        state = angle >= 0.02 if state else angle > 0.1
        assert interventions.human[t] == state, t
    expected = np.where(interventions.human, [cartpole(o) for o in episode.observations[:-1]], 0)
    np.testing.assert_array_equal(interventions.executed_actions, expected)
    np.testing.assert_array_equal(episode.actions, expected)
    np.testing.assert_array_equal(interventions.proposed_actions, np.zeros(len(episode)))
    handovers = interventions.handovers()
    assert [to_human for _, to_human in handovers] == [True, False] * (len(handovers) // 2) + [True] * (len(handovers) % 2)
    assert episode.metadata["expert_steps"] == interventions.human.sum()
    assert episode.timestamps is not None and np.all(np.diff(episode.timestamps) >= 0)


def test_intervention_channels_round_trip_one_json_message_per_step_and_one_per_handover(tmp_path: Path) -> None:
    from mcap.reader import make_reader

    human = np.array([False, True, True, False, True])
    episode = Episode(
        observations=np.arange(24, dtype=np.float32).reshape(6, 4),
        actions=np.array([0, 1, 1, 0, 1]),
        rewards=np.ones(5),
        interventions=Interventions(human=human, proposed_actions=np.zeros(5, np.int64), executed_actions=np.array([0, 1, 1, 0, 1])),
    )
    path = write_episodes(tmp_path / "round.mcap", [episode], env_id="CartPole-v1", observation_space=BOX, action_space=gym.spaces.Discrete(2), dt=0.02)
    back = DemoFile(path)[0]
    assert back.interventions is not None
    np.testing.assert_array_equal(back.interventions.human, human)
    np.testing.assert_array_equal(back.interventions.proposed_actions, np.zeros(5))
    np.testing.assert_array_equal(back.interventions.executed_actions, episode.actions)
    with open(path, "rb") as stream:
        messages = [(channel.topic, message.log_time, json.loads(message.data)) for _, channel, message in make_reader(stream).iter_messages(topics=[
            "/intervention/human", "/intervention/handover", "/intervention/executed_action"])]
    step_ns = 20_000_000
    assert [(t, body) for topic, t, body in messages if topic == "/intervention/handover"] == [
        (step_ns, {"step": 1, "to": "human"}), (3 * step_ns, {"step": 3, "to": "learner"}), (4 * step_ns, {"step": 4, "to": "human"})]
    assert [body["human"] for topic, _, body in messages if topic == "/intervention/human"] == human.tolist()
    assert [t for topic, t, _ in messages if topic == "/intervention/executed_action"] == [i * step_ns for i in range(5)]


def test_a_file_whose_intervention_channels_miss_a_step_is_refused_naming_the_channel(tmp_path: Path) -> None:
    from imitation.data.mcap import writer as writer_module

    episode = Episode(
        observations=np.zeros((4, 4), np.float32), actions=np.zeros(3, np.int64), rewards=np.zeros(3),
        interventions=Interventions(human=np.ones(3, bool), proposed_actions=np.zeros(3, np.int64), executed_actions=np.zeros(3, np.int64)),
    )
    original = writer_module._intervention_messages

    def drop_last_proposal(interventions):
        messages = original(interventions)
        messages[2] = [m for m in messages[2] if m[0] != "/intervention/proposed_action"]
        return messages

    writer_module._intervention_messages = drop_last_proposal
    try:
        path = write_episodes(tmp_path / "short.mcap", [episode], env_id="CartPole-v1", observation_space=BOX, action_space=gym.spaces.Discrete(2))
    finally:
        writer_module._intervention_messages = original
    with pytest.raises(DemoFileError, match="episode 0: /intervention/proposed_action holds 2 messages, expected 3"):
        DemoFile(path)[0]


def test_bc_keeps_only_the_steps_a_person_drove_and_refuses_files_that_do_not_say(tmp_path: Path) -> None:
    rounds = tmp_path / "round.mcap"
    human = np.array([True, False, True, True])
    episode = Episode(
        observations=np.zeros((5, 4), np.float32), actions=np.zeros(4, np.int64), rewards=np.zeros(4),
        interventions=Interventions(human=human, proposed_actions=np.zeros(4, np.int64), executed_actions=np.zeros(4, np.int64)),
    )
    plain = Episode(observations=np.zeros((3, 4), np.float32), actions=np.zeros(2, np.int64), rewards=np.zeros(2))
    write_episodes(rounds, [episode], env_id="CartPole-v1", observation_space=BOX, action_space=gym.spaces.Discrete(2))
    demos = write_episodes(tmp_path / "demos.mcap", [plain], env_id="CartPole-v1", observation_space=BOX, action_space=gym.spaces.Discrete(2))
    dataset = DemoDataset([demos, rounds])
    assert human_steps(dataset, [1, 0], unrecorded=True).tolist() == [True, True, *human.tolist()]
    with pytest.raises(ImitationError, match=r"demos.mcap: episode 0 does not record who drove it \(no /intervention channels\)"):
        human_steps(dataset, [0, 1])


def standin_dagger(round_dir: Path, *, label: str = "human", rounds: int = 3) -> DAgger:
    env = gym.make("CartPole-v1")
    bc = BCConfig(epochs=20, patience=20, hidden_sizes=[32], seed=0, device="cpu")
    config = DAggerConfig(rounds=rounds, episodes_per_round=2, mode="takeover", label=label, seed=0, bc=bc)
    policy = make_policy(env.observation_space, env.action_space, **policy_options(bc))
    return DAgger(env, StandIn("CartPole-v1"), policy, config, round_dir=round_dir, env_id="CartPole-v1")


@pytest.mark.parametrize("label", ["human", "all"])
def test_takeover_dagger_counts_as_labels_only_the_steps_the_standin_drove_unless_told_all(tmp_path: Path, label: str) -> None:
    """Round 1 already has a learner (the untrained policy) for the person to correct."""
    dagger = standin_dagger(tmp_path / "rounds", label=label, rounds=2)
    history = run(dagger)
    episodes = DemoDataset(dagger.files).read_episodes()
    human = sum(int(episode.interventions.human.sum()) for episode in episodes)
    steps = sum(len(episode) for episode in episodes)
    assert 0 < human < steps
    assert history[-1]["expert_labels"] == (human if label == "human" else steps)
    first_round = DemoFile(dagger.files[0]).read_episodes()
    rate = sum(int(e.interventions.human.sum()) for e in first_round) / sum(len(e) for e in first_round)
    assert history[0]["intervention_rate"] == pytest.approx(rate)
    assert DemoFile(dagger.files[0]).user_metadata["mode"] == "takeover"


def test_takeover_needs_an_expert_that_takes_the_controls(tmp_path: Path) -> None:
    scripted, bad_label, pendulum = run_cli_many([
        ["train", "dagger", "--env", "CartPole-v1", "--expert", "scripted", "--mode", "takeover", "--out", str(tmp_path / "a")],
        ["train", "dagger", "--env", "CartPole-v1", "--expert", "standin", "--label", "some", "--out", str(tmp_path / "b")],
        ["train", "dagger", "--env", "Pendulum-v1", "--expert", "standin", "--mode", "takeover", "--out", str(tmp_path / "c")],
    ])
    assert_one_line_error(scripted, "--mode takeover needs an expert that takes the controls (standin, keyboard, gamepad, pointer), not scripted")
    assert "argument --label: invalid choice: 'some'" in bad_label.stderr and bad_label.returncode == 2
    assert_one_line_error(pendulum, "--expert standin has no take-over condition for Pendulum-v1")
    assert not any(tmp_path.iterdir())


def test_cli_takeover_dagger_with_the_standin_reaches_475_as_interventions_fall(tmp_path: Path) -> None:
    """The issue's command: `train dagger --env CartPole-v1 --expert standin --mode takeover
    --rounds 5`; `imitation info RUN_DIR` reports the rate by round and pymcap-cli lists the
    intervention channels of a round file and passes it as sound MCAP."""
    out = tmp_path / "hg"
    result = run_cli("train", "dagger", "--env", "CartPole-v1", "--expert", "standin", "--mode", "takeover", "--rounds", "5", "--seed", "0",
                     "--quiet", "--json", "--out", str(out), timeout=600, env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert result.returncode == 0, result.stderr[-3000:]
    metrics = last_json(result)
    rates = metrics["intervention_rates"]
    assert metrics["eval"]["mean_return"] >= 475
    assert rates[0] > 0.05 and rates[-1] < rates[0] and all(later <= earlier for earlier, later in zip(rates, rates[1:]))
    assert metrics["expert_labels"] < 2500, "fewer labels than one round of the expert driving alone"
    assert (out / "intervention_curve.png").stat().st_size > 0
    info = run_cli("info", str(out))
    assert info.returncode == 0, info.stderr
    lines = info.stdout.strip().splitlines()
    assert len(lines) == 5 and lines[0].startswith("round-01.mcap:") and f"({100 * rates[0]:.1f} %)" in lines[0]
    tool = Path(sys.executable).parent / "pymcap-cli"
    if not tool.exists():
        pytest.skip("pymcap-cli is not installed (it is a dev dependency: pip install -e .[dev])")
    listing = subprocess.run([str(tool), "info", str(out / "rounds" / "round-01.mcap")], capture_output=True, text=True, timeout=120,
                             env={"COLUMNS": "200", "PATH": "/usr/bin:/bin"})
    for topic in ("/intervention/human", "/intervention/proposed_action", "/intervention/executed_action", "/intervention/handover", "/time"):
        assert topic in listing.stdout, listing.stdout
    doctor = subprocess.run([str(tool), "doctor", str(out / "rounds" / "round-01.mcap")], capture_output=True, text=True, timeout=120,
                            env={"COLUMNS": "200", "PATH": "/usr/bin:/bin"})
    assert doctor.returncode == 0 and "passed MCAP doctor checks" in doctor.stdout, doctor.stdout


# -- a kill or Ctrl-C in the middle of a round ----------------------------------------------------

EPISODES = 60  # round 2 lasts about 5 s (80 ms an episode): ample time to be stopped after its third episode
ROUND_ARGS = ["train", "dagger", "--env", "CartPole-v1", "--expert", "scripted", "--rounds", "2", "--episodes-per-round", str(EPISODES),
              "--epochs", "2", "--hidden", "16", "--seed", "0", "--quiet", "--json"]


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory: pytest.TempPathFactory) -> list[Episode]:
    """Round 2 of the run that nothing stopped."""
    out = tmp_path_factory.mktemp("whole") / "run"
    result = run_cli(*ROUND_ARGS, "--out", str(out), timeout=600, env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert result.returncode == 0, result.stderr[-3000:]
    return DemoFile(out / "rounds" / "round-02.mcap").read_episodes()


def start(*args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, str(REPO / "cli.py"), *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO,
                            env={**os.environ, "OMP_NUM_THREADS": "1"})


def stop_mid_round(process: subprocess.Popen, partial: Path, stop: str) -> None:
    """Once round 2's file holds 3 finished episodes, kill -9 the process or press Ctrl-C twice."""
    deadline = time.monotonic() + 300
    try:
        while not (partial.exists() and salvageable_episodes(partial) >= 3):
            assert process.poll() is None, f"dagger ended before it was stopped: {process.communicate()[1][-2000:]}"
            assert time.monotonic() < deadline
            time.sleep(0.02)
        if stop == "kill":
            os.kill(process.pid, signal.SIGKILL)
        else:
            process.send_signal(signal.SIGINT)  # the first waits for the round's end,
            time.sleep(0.2)
            process.send_signal(signal.SIGINT)  # the second stops at once
        process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            process.kill()


@pytest.mark.parametrize("stop", ["kill", "ctrl-c"])
def test_a_round_stopped_midway_keeps_its_finished_episodes_and_resume_completes_it_as_if_uninterrupted(
    tmp_path: Path, stop: str, uninterrupted: list[Episode]
) -> None:
    """kill -9 leaves round-02.mcap.partial, a double Ctrl-C closes round-02.mcap with the finished
    episodes; either way --resume keeps them (bit-exact, first in the round) and runs the rest of
    the round, its β-mixture draws included, as the uninterrupted run does."""
    out = tmp_path / "stopped"
    process = start(*ROUND_ARGS, "--out", str(out))
    stop_mid_round(process, tmp_path / "stopped.partial" / "rounds" / "round-02.mcap.partial", stop)
    rounds = tmp_path / "stopped.partial" / "rounds"
    if stop == "kill":
        assert process.returncode == -signal.SIGKILL
        kept = DemoFile(rounds / "round-02.mcap.partial", salvage=True).read_episodes()
    else:
        assert process.returncode == 130
        assert not (rounds / "round-02.mcap.partial").exists()
        kept = DemoFile(rounds / "round-02.mcap").read_episodes()
    assert 3 <= len(kept) < EPISODES
    resumed = run_cli(*ROUND_ARGS, "--out", str(out), "--resume", timeout=600, env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    final = DemoFile(out / "rounds" / "round-02.mcap").read_episodes()
    assert len(final) == EPISODES and not (out / "rounds" / "round-02.mcap.partial").exists()
    for before, after in zip(kept, final):
        np.testing.assert_array_equal(before.observations, after.observations)
        np.testing.assert_array_equal(before.timestamps, after.timestamps)
    for ours, theirs in zip(final, uninterrupted, strict=True):
        np.testing.assert_array_equal(ours.observations, theirs.observations)
        np.testing.assert_array_equal(ours.interventions.human, theirs.interventions.human)


def test_train_bc_on_the_steps_a_person_drove(tmp_path: Path) -> None:
    """`train bc --steps human` keeps the person's steps of round files, and refuses files where
    the person never drove, naming the file."""
    env = gym.make("CartPole-v1")

    def round_file(name: str, *, standin_drives: bool) -> Path:
        episodes = [
            run_episode(env, lambda observation: 0, StandIn("CartPole-v1", engage=0.1 if standin_drives else 1.0), mode="takeover",
                        seed=seed, rng=np.random.default_rng(0), metadata={})
            for seed in range(4)
        ]
        return write_episodes(tmp_path / name, episodes, env_id="CartPole-v1", observation_space=env.observation_space, action_space=env.action_space)

    driven, untouched = round_file("driven.mcap", standin_drives=True), round_file("untouched.mcap", standin_drives=False)
    ok, refused = run_cli_many([
        ["train", "bc", "--demos", str(driven), "--env", "CartPole-v1", "--steps", "human", "--epochs", "1", "--quiet", "--json", "--out", str(tmp_path / "ok")],
        ["train", "bc", "--demos", str(untouched), "--env", "CartPole-v1", "--steps", "human", "--epochs", "1", "--quiet", "--out", str(tmp_path / "no")],
    ])
    person = sum(int(episode.interventions.human.sum()) for episode in DemoFile(driven))
    metrics = last_json(ok)
    assert 0 < person < DemoFile(driven).num_transitions
    assert metrics["train_transitions"] + metrics["validation_transitions"] == person
    assert_one_line_error(refused, f"{untouched}: no step of the training episodes was driven by a person")


def test_a_round_in_which_the_expert_never_takes_over_keeps_the_learner_as_it_was(tmp_path: Path) -> None:
    env = gym.make("CartPole-v1")
    bc = BCConfig(epochs=5, patience=5, hidden_sizes=[8], seed=0, device="cpu")
    policy = make_policy(env.observation_space, env.action_space, **policy_options(bc))
    before = {name: tensor.clone() for name, tensor in policy.state_dict().items()}
    config = DAggerConfig(rounds=1, episodes_per_round=2, mode="takeover", seed=0, bc=bc)
    dagger = DAgger(env, StandIn("CartPole-v1", engage=1.0), policy, config, round_dir=tmp_path / "rounds", env_id="CartPole-v1")
    (row,) = run(dagger)
    assert row["expert_labels"] == 0 and row["intervention_rate"] == 0 and np.isnan(row["validation_loss"])
    assert all(np.array_equal(before[name], tensor) for name, tensor in dagger.policy.state_dict().items())


def test_a_first_round_killed_midway_resumes_from_the_start_of_the_run_with_its_finished_episodes(tmp_path: Path) -> None:
    """The run's first checkpoint is written before round 1, so --resume works from there too."""
    out = tmp_path / "first"
    args = [*ROUND_ARGS[:6], "--rounds", "1", "--episodes-per-round", "40", *ROUND_ARGS[10:], "--out", str(out)]
    process = start(*args)
    stop_mid_round(process, tmp_path / "first.partial" / "rounds" / "round-01.mcap.partial", "kill")
    kept = DemoFile(tmp_path / "first.partial" / "rounds" / "round-01.mcap.partial", salvage=True).read_episodes()
    resumed = run_cli(*args, "--resume", timeout=600, env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    final = DemoFile(out / "rounds" / "round-01.mcap").read_episodes()
    assert 3 <= len(kept) < 40 == len(final)
    for before, after in zip(kept, final):
        np.testing.assert_array_equal(before.timestamps, after.timestamps)


def test_an_interrupted_round_resumes_from_whichever_of_its_file_and_partial_holds_more(tmp_path: Path) -> None:
    """A run killed while a resumed round rewrote its kept episodes leaves both round-NN.mcap and
    a partial that begins with the same episodes: the longer wins, the other goes."""
    from imitation.algorithms.dagger import finished_episodes
    from imitation.data.mcap.writer import DemoWriter

    env = gym.make("CartPole-v1")
    episodes = collect_round(env, None, cartpole, beta=1.0, episodes=3, seed=0, rng=np.random.default_rng(0), metadata={})
    spaces = {"env_id": "CartPole-v1", "observation_space": env.observation_space, "action_space": env.action_space}
    path, partial = tmp_path / "round-02.mcap", tmp_path / "round-02.mcap.partial"

    def killed_writer(count: int) -> None:
        writer = DemoWriter(tmp_path / "writing.mcap", flush_episodes=True, **spaces)
        for episode in episodes[:count]:
            writer.write(episode)
        partial.write_bytes((tmp_path / "writing.mcap.partial").read_bytes())  # what a kill leaves
        writer.abort()
        (tmp_path / "writing.mcap.partial").unlink(missing_ok=True)

    write_episodes(path, episodes[:2], **spaces)
    killed_writer(3)
    kept = finished_episodes(path)
    assert len(kept) == 3 and len(DemoFile(path)) == 3 and not partial.exists()
    killed_writer(1)
    assert len(finished_episodes(path)) == 3 and not partial.exists()
    for ours, original in zip(DemoFile(path).read_episodes(), episodes, strict=True):
        np.testing.assert_array_equal(ours.observations, original.observations)
