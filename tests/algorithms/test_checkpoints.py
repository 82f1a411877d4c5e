"""Checkpoints hold the whole training state: BC, DAgger and tabular IRL resumed from one end bit
for bit where an uninterrupted run ends; PPO's round trip restores networks, optimiser,
normalisers and random generators exactly, and GCL's reward learner, saved in PPO's checkpoint,
goes on exactly as the original would; Ctrl-C stops at an update boundary with a checkpoint saved.
(PPO itself does not resume bit for bit: its environments start new episodes.) The one training
loop that saves and resumes them all is pinned on a fake learner at the end."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from support import DATASETS

import imitation.envs  # noqa: F401  (registers the ids)
from imitation.algorithms.bc import BCConfig, BehaviouralCloning, policy_options
from imitation.algorithms.dagger import DAgger, DAggerConfig
from imitation.algorithms.gcl import GCLConfig, GuidedCostLearning, RewardLearner
from imitation.algorithms.maxent_irl import MaxEntIRL, MaxEntIRLConfig
from imitation.algorithms.ppo import PPO, PPOConfig
from imitation.checkpoints import snapshot
from imitation.data.loader import load_transitions, transitions_to_torch
from imitation.data.mcap.reader import DemoFile
from imitation.envs.rollout import Rollout
from imitation.envs.tabular import gridworld
from imitation.envs.tabular_planning import Dynamics, soft_optimal_policy, state_visitation
from imitation.errors import ImitationError
from imitation.experts.scripted import cartpole
from imitation.jobs.loop import Checkpointing, TrainingInterrupted, run
from imitation.jobs.presets import ppo_settings
from imitation.policies import make_policy
from imitation.rewards import make_reward_model
from imitation.runs import read_checkpoint, save_checkpoint

CONFIG = BCConfig(epochs=12, patience=12, batch_size=128, hidden_sizes=[16], seed=4, device="cpu")


@pytest.fixture(scope="module")
def demos():
    demo = DemoFile(DATASETS / "CartPole-v1.mcap")
    data = transitions_to_torch(load_transitions(DATASETS / "CartPole-v1.mcap", episodes=range(6)))
    validation = transitions_to_torch(load_transitions(DATASETS / "CartPole-v1.mcap", episodes=[6, 7]))
    return demo, data, validation


def fresh_policy(demo):
    torch.manual_seed(0)
    return make_policy(demo.observation_space, demo.action_space, **policy_options(CONFIG))


def test_bc_resumed_from_a_ctrl_c_checkpoint_ends_exactly_where_an_uninterrupted_run_does(demos, tmp_path: Path) -> None:
    demo, data, validation = demos
    whole = BehaviouralCloning(fresh_policy(demo), data, validation, CONFIG)
    whole_history = run(whole)

    saved = []

    def press_ctrl_c_during_epoch_5(policy) -> float:
        os.kill(os.getpid(), signal.SIGINT)  # deferred to the end of the epoch
        return 0.0

    def save(tensors, state) -> None:
        save_checkpoint(tmp_path, tensors, {"trainer": state})  # through the files, as a run does
        saved.append(state["epoch"])

    stopped_rows = []
    with pytest.raises(TrainingInterrupted, match="BC stopped after epoch 5 of 12"):
        stopped = BehaviouralCloning(fresh_policy(demo), data, validation, CONFIG, evaluate=press_ctrl_c_during_epoch_5, evaluate_every=5)
        run(stopped, log=stopped_rows.append, checkpoints=Checkpointing(save=save, every=2))
    assert saved == [3, 5, 6], "every 2 epochs, and at the interruption"
    tensors, state = read_checkpoint(tmp_path)
    resumed = BehaviouralCloning(fresh_policy(demo), data, validation, CONFIG)
    torch.manual_seed(123)  # the resumed process's generators start elsewhere: the checkpoint must set them
    resumed_rows = run(resumed, checkpoints=Checkpointing(save=lambda *a: None, resume=(tensors, state["trainer"])))
    # run() returns the rows of its own call: the history of the run is the stopped run's rows
    # up to the checkpoint (its next epoch excluded) and then the resumed call's.
    history = [row for row in stopped_rows if row["epoch"] < state["trainer"]["epoch"]] + resumed_rows
    assert [row["epoch"] for row in history] == list(range(1, 13))
    assert resumed.best_epoch == whole.best_epoch
    assert [row["validation_loss"] for row in history] == [row["validation_loss"] for row in whole_history]
    for name, tensor in whole.policy.state_dict().items():
        assert torch.equal(resumed.policy.state_dict()[name], tensor), name


def test_ppo_checkpoint_round_trip_is_exact(demos) -> None:
    _, data, _ = demos
    # 4 envs (the scaler's), 8 updates in all, so that the checkpoint's next update 7 lies in the run.
    config = PPOConfig(env_id="CartPole-v1", total_steps=8 * 4 * 16, n_envs=4, n_steps=16, gamma=0.99, learning_rate=1e-3,
                       normalize_observations=True, normalize_rewards=True, device="cpu")
    original = PPO(config)
    policy, optimizer, scaler = original.policy, original.optimizer, original.reward_scaler
    for _ in range(3):  # some optimiser, normaliser and scaler state
        policy.update_normalizer(data.observations[:64])
        loss = policy.value(policy.encode(data.observations[:64])).pow(2).mean()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        scaler(np.random.default_rng(0).normal(size=4), np.zeros(4, dtype=bool))
    original.updates, original.global_step, original.beta, original.clock.before = 7, 1792, 0.5, 12.5
    original.recent_returns.extend([1.0, 2.0])
    original.recent_optimised_returns.extend([3.0])
    original.timers["env"] = 1.0
    checkpoint = snapshot(*original.state_dict())
    expected_next = (torch.rand(3), np.random.random(3))

    torch.manual_seed(99)
    copy = PPO(config)
    copy.load_state_dict(checkpoint)
    counters = (copy.updates, copy.global_step, copy.beta, copy.clock.before)
    assert counters == (7, 1792, 0.5, 12.5)
    for name, tensor in policy.state_dict().items():
        assert torch.equal(copy.policy.state_dict()[name], tensor), name
    assert len(copy.optimizer.state) == len(optimizer.state) > 0
    for mine, theirs in zip(optimizer.state.values(), copy.optimizer.state.values()):
        assert all(torch.equal(mine[key], theirs[key]) for key in mine)
    assert all(torch.equal(copy.reward_scaler.stats.state_dict()[name], t) for name, t in scaler.stats.state_dict().items())
    assert list(copy.recent_returns) == [1.0, 2.0] and list(copy.recent_optimised_returns) == [3.0]
    assert copy.timers == original.timers and copy.timers["env"] == 1.0
    assert torch.equal(torch.rand(3), expected_next[0]) and np.array_equal(np.random.random(3), expected_next[1])

    with pytest.raises(ImitationError, match="the checkpoint does not fit this PPO run"):
        PPO(config).load_state_dict(({}, {}))
    original.close()
    copy.close()


def test_ppo_resumes_to_the_requested_total() -> None:
    config = PPOConfig(env_id="CartPole-v1", total_steps=2560, n_envs=2, n_steps=128, seed=0, device="cpu")
    saved = []
    first = PPO(config)
    first_rows = run(first, checkpoints=Checkpointing(save=lambda tensors, state: saved.append((tensors, state)), every=3))
    first.close()
    assert [state["update"] for _, state in saved] == [3, 6, 9, 10], "every 3 of 10 updates, and after the last"
    resumed = PPO(config)
    resumed_rows = run(resumed, checkpoints=Checkpointing(save=lambda *a: None, resume=saved[0]))
    resumed.close()
    # run() returns the rows of its own call: the resumed call's start after the checkpoint's
    # 3 updates, and with the first run's rows before it they make the whole run's.
    history = first_rows[: saved[0][1]["update"]] + resumed_rows
    assert resumed.global_step == 2560 and [row["step"] for row in history] == [256.0 * (i + 1) for i in range(10)]
    assert [row["step"] for row in resumed_rows] == [256.0 * (i + 1) for i in range(3, 10)]


def press_ctrl_c(*_) -> float:
    """An evaluate/log callback: Ctrl-C in the middle of a round, iteration or update."""
    os.kill(os.getpid(), signal.SIGINT)
    return 0.0


def through_files(folder: Path, checkpoint):
    """A checkpoint written and read back as a run does."""
    folder.mkdir(exist_ok=True)
    save_checkpoint(folder, *snapshot(checkpoint[0], {"trainer": checkpoint[1]}))
    tensors, state = read_checkpoint(folder)
    return tensors, state["trainer"]


def test_dagger_resumed_from_a_ctrl_c_checkpoint_ends_exactly_where_an_uninterrupted_run_does(tmp_path: Path) -> None:
    env = gym.make("CartPole-v1")
    config = DAggerConfig(rounds=3, episodes_per_round=1, seed=2, bc=BCConfig(epochs=3, patience=3, hidden_sizes=[16], seed=2, device="cpu"))

    def dagger(folder: str, evaluate=None, **options):
        """The learner and the rows of its run() call."""
        torch.manual_seed(0)
        policy = make_policy(env.observation_space, env.action_space, **policy_options(config.bc))
        learner = DAgger(env, cartpole, policy, config, round_dir=tmp_path / folder, env_id="CartPole-v1", evaluate=evaluate)
        return learner, run(learner, **options)

    whole, whole_history = dagger("whole")
    saved, stopped_rows = [], []
    with pytest.raises(TrainingInterrupted, match="DAgger stopped after round 1 of 3"):
        dagger("stopped", evaluate=press_ctrl_c, log=stopped_rows.append,
               checkpoints=Checkpointing(save=lambda *checkpoint: saved.append(through_files(tmp_path / "ckpt", checkpoint))))
    assert [state["round"] for _, state in saved] == [2] and saved[0][1]["round_files"] == ["round-01.mcap"]
    recorded = (tmp_path / "stopped" / "round-01.mcap").stat()
    torch.manual_seed(123)  # the resumed process's generators start elsewhere: the checkpoint and the seeds must set them
    resumed, resumed_rows = dagger("stopped", checkpoints=Checkpointing(save=lambda *a: None, resume=saved[0]))
    assert (tmp_path / "stopped" / "round-01.mcap").stat().st_mtime_ns == recorded.st_mtime_ns, "round 1 is reused, not recorded again"
    assert [path.name for path in resumed.files] == ["round-01.mcap", "round-02.mcap", "round-03.mcap"]
    # run() returns the rows of its own call: the stopped run's rows up to the checkpoint, then the resumed call's.
    history = [row for row in stopped_rows if row["round"] < saved[0][1]["round"]] + resumed_rows
    for column in ("beta", "expert_labels", "rollout_return", "validation_loss"):
        np.testing.assert_array_equal([row[column] for row in history], [row[column] for row in whole_history], err_msg=column)
    for name, tensor in whole.policy.state_dict().items():
        assert torch.equal(resumed.policy.state_dict()[name], tensor), name
    with pytest.raises(ImitationError, match="the checkpoint does not fit this DAgger run"):
        dagger("other", checkpoints=Checkpointing(save=lambda *a: None, resume=({}, {})))


def test_tabular_irl_resumed_from_a_ctrl_c_checkpoint_ends_exactly_where_an_uninterrupted_run_does(tmp_path: Path) -> None:
    mdp = gridworld()
    target = state_visitation(Dynamics.of(mdp.transition), mdp.initial, soft_optimal_policy(mdp), horizon=mdp.horizon, discount=1.0)
    config = MaxEntIRLConfig(iterations=30, tolerance=0.0, hidden_sizes=[8])

    def model():
        torch.manual_seed(0)
        return make_reward_model(gym.spaces.Discrete(mdp.n_states), gym.spaces.Discrete(mdp.n_actions), feature_table=mdp.features, hidden_sizes=[8])

    whole = MaxEntIRL(mdp, target, model(), config)
    whole_history = run(whole)
    saved, stopped_rows = [], []

    def log(row) -> None:
        stopped_rows.append(row)
        if row["iteration"] == 7:
            press_ctrl_c()

    with pytest.raises(TrainingInterrupted, match="mce IRL stopped after iteration 7 of 30"):
        run(MaxEntIRL(mdp, target, model(), config), log=log, checkpoints=Checkpointing(save=lambda *c: saved.append(through_files(tmp_path, c)), every=5))
    assert [state["iteration"] for _, state in saved] == [6, 8], "every 5 iterations, and at the interruption"
    resumed = MaxEntIRL(mdp, target, model(), config)
    resumed_rows = run(resumed, checkpoints=Checkpointing(save=lambda *a: None, resume=saved[-1]))
    # run() returns the rows of its own call: the stopped run's rows up to the checkpoint, then the resumed call's.
    history = [row for row in stopped_rows if row["iteration"] < saved[-1][1]["iteration"]] + resumed_rows
    assert [row["iteration"] for row in history] == list(range(1, 31))
    assert [row["loss"] for row in history] == [row["loss"] for row in whole_history]
    for name, tensor in whole.reward_model.state_dict().items():
        assert torch.equal(resumed.reward_model.state_dict()[name], tensor), name
    with pytest.raises(ImitationError, match="the checkpoint does not fit this tabular IRL run"):
        run(MaxEntIRL(mdp, target, model(), config), checkpoints=Checkpointing(save=lambda *a: None, resume=({}, {})))


GCL_ENV = "imitation/CartPoleFixedHorizon-v0"
GCL_CONFIG = GCLConfig(warmup_steps=20, reward_steps=4, batch_size=64)


def gcl_reward(seed: int):
    env = gym.make(GCL_ENV)
    demos = transitions_to_torch(load_transitions(DATASETS / "CartPoleFixedHorizon-v0.mcap", next_observations=True))
    torch.manual_seed(seed)
    reward = make_reward_model(env.observation_space, env.action_space, hidden_sizes=[16], normalize_observations=True)
    return reward, demos


def reward_learner(seed: int, updates: int = 3) -> RewardLearner:
    reward, demos = gcl_reward(seed)
    return RewardLearner(reward, demos, GCL_CONFIG, updates=updates)


def gcl_learner(seed: int, config: PPOConfig) -> GuidedCostLearning:
    reward, demos = gcl_reward(seed)
    return GuidedCostLearning(PPO(config), reward, demos, GCL_CONFIG)


def learn_from(learner: RewardLearner, rollout: Rollout, policy):
    """What the old hook's call did: pool the rollout, learn, and the rewards PPO would optimise
    (r_θ minus α log π_k), with the reward update's statistics."""
    log_pi = learner.add_rollout(rollout, policy)
    statistics = learner.learn()
    return learner.reward.relabel(rollout) - learner.config.policy_entropy * log_pi, statistics


def demo_rollout(start: int) -> Rollout:
    """64 demo steps shaped as a rollout of 32 steps × 2 envs (fresh tensors, as PPO's are not)."""
    demos = transitions_to_torch(load_transitions(DATASETS / "CartPoleFixedHorizon-v0.mcap", next_observations=True))
    rows = slice(start, start + 64)

    def shaped(tensor: torch.Tensor) -> torch.Tensor:
        return tensor[rows].reshape(32, 2, *tensor.shape[1:]).clone()

    return Rollout(
        observations=shaped(demos.observations), actions=shaped(demos.actions), env_actions=shaped(demos.actions),
        next_observations=shaped(demos.next_observations), log_probs=torch.full((32, 2), -0.7), env_rewards=torch.zeros(32, 2),
        terminated=torch.zeros(32, 2, dtype=torch.bool), truncated=torch.zeros(32, 2, dtype=torch.bool),
    )


def test_gcl_learner_restored_from_its_checkpoint_goes_on_exactly_as_the_original(tmp_path: Path) -> None:
    env = gym.make(GCL_ENV)
    policy = make_policy(env.observation_space, env.action_space)
    original = reward_learner(seed=0)
    learn_from(original, demo_rollout(0), policy)
    tensors, state = through_files(tmp_path, original.state_dict())
    copy = reward_learner(seed=1)  # other initial weights: the checkpoint must set them
    copy.load_state_dict((tensors, state))
    copy_rewards, copy_statistics = learn_from(copy, demo_rollout(64), policy)
    original_rewards, original_statistics = learn_from(original, demo_rollout(64), policy)
    assert torch.equal(copy_rewards, original_rewards)
    for name, tensor in original.reward.state_dict().items():
        assert torch.equal(copy.reward.state_dict()[name], tensor), name
    assert torch.equal(copy.pool.observations, original.pool.observations) and len(copy.pool.log_mass) == 128 and len(copy.samplers) == len(original.samplers) > 0
    assert torch.equal(copy.generator.get_state(), original.generator.get_state())
    assert copy_statistics == original_statistics and copy.learned == original.learned == 2
    assert torch.equal(copy.log_partition, original.log_partition)
    assert len(copy.optimizer.state) == len(original.optimizer.state) > 0
    for mine, theirs in zip(original.optimizer.state.values(), copy.optimizer.state.values()):
        assert all(torch.equal(mine[key], theirs[key]) for key in mine)


def test_gcl_learner_rides_in_ppo_checkpoints_and_resumes_with_them() -> None:
    config = PPOConfig(env_id=GCL_ENV, total_steps=4 * 256, **ppo_settings(GCL_ENV) | {"device": "cpu"})
    saved = []
    first = gcl_learner(seed=0, config=config)
    try:
        first_rows = run(first, checkpoints=Checkpointing(save=lambda tensors, state: saved.append((tensors, state)), every=2))
    finally:
        first.ppo.close()
    tensors, state = saved[0]
    assert state["update"] == 2 and state["learner"]["learned"] == 2 and tensors["learner.pool.log_mass"].shape == (512,)
    resumed = gcl_learner(seed=1, config=config)
    try:
        resumed_rows = run(resumed, checkpoints=Checkpointing(save=lambda *a: None, resume=saved[0]))
    finally:
        resumed.ppo.close()
    # The reward learner's count of updates comes from the checkpoint; its rows before it are the first run's.
    assert resumed.rewards.learned == 4 and len(first_rows[:2] + resumed_rows) == 4 and all("reward_loss" in row for row in resumed_rows)
    assert len(resumed.rewards.pool.log_mass) == 4 * 256 and len(resumed.rewards.samplers) == 4, "the pool kept the rollouts from before the interruption"
    other = gcl_learner(seed=1, config=config)
    try:
        with pytest.raises(ImitationError, match="the checkpoint does not fit this PPO run"):
            run(other, checkpoints=Checkpointing(save=lambda *a: None, resume=(tensors, {k: v for k, v in state.items() if k != "learner"})))
    finally:
        other.ppo.close()


class FakeLearner:
    """The least a learner is for the loop: counts its steps, sends itself Ctrl-C during step
    `interrupt_at`, and records what the loop asked of it, in order."""

    name = "Fake"
    unit = "tick"

    def __init__(self, total: int = 10, *, interrupt_at: int | None = None) -> None:
        self.total = total
        self.steps = 0
        self.interrupt_at = interrupt_at
        self.events: list[str] = []

    @property
    def completed(self) -> int:
        return self.steps

    @property
    def done(self) -> bool:
        return self.steps >= self.total

    def position(self) -> str:
        return f"tick {self.steps} of {self.total}"

    def progress(self, row) -> dict[str, str]:
        return {"tick": str(int(row["tick"]))}

    def step(self) -> dict[str, float]:
        self.steps += 1
        self.events.append(f"step {self.steps}")
        if self.steps == self.interrupt_at:
            os.kill(os.getpid(), signal.SIGINT)  # deferred to the end of the step
        return {"tick": float(self.steps)}

    def state_dict(self):
        self.events.append(f"save {self.steps}")
        return {"weight": torch.tensor([float(self.steps)])}, {"next": self.steps + 1}

    def load_state_dict(self, checkpoint) -> None:
        tensors, state = checkpoint
        self.steps = state["next"] - 1
        self.events.append(f"load {self.steps}")


def test_the_loop_saves_every_interval_stops_on_ctrl_c_with_a_checkpoint_and_resumes_to_the_total() -> None:
    # Every `every` steps, and after the last one (whatever the job does next can then be resumed).
    saved = []
    learner = FakeLearner(10)
    rows = run(learner, checkpoints=Checkpointing(save=lambda tensors, state: saved.append((tensors, state)), every=5))
    assert [row["tick"] for row in rows] == [float(i) for i in range(1, 11)]
    assert [state["next"] for _, state in saved] == [6, 11]
    assert learner.events == [f"step {i}" for i in range(1, 6)] + ["save 5"] + [f"step {i}" for i in range(6, 11)] + ["save 10"]
    # The default interval is a tenth of the run.
    saved.clear()
    run(FakeLearner(20), checkpoints=Checkpointing(save=lambda tensors, state: saved.append((tensors, state))))
    assert [state["next"] for _, state in saved] == [3, 5, 7, 9, 11, 13, 15, 17, 19, 21]
    # `at_start`: one before the first step too, unless resumed.
    saved.clear()
    started = FakeLearner(3)
    keep = lambda tensors, state: saved.append((tensors, state))  # noqa: E731
    run(started, checkpoints=Checkpointing(save=keep, every=5, at_start=keep))
    assert [state["next"] for _, state in saved] == [1, 4] and started.events[0] == "save 0"

    # Ctrl-C during a step: the step finishes, a checkpoint is saved, and the message is "{name} stopped after {position}".
    saved.clear()
    logged = []
    stopped = FakeLearner(10, interrupt_at=4)
    handler = signal.getsignal(signal.SIGINT)
    with pytest.raises(TrainingInterrupted, match=r"^Fake stopped after tick 4 of 10$"):
        run(stopped, log=logged.append, checkpoints=Checkpointing(save=lambda tensors, state: saved.append((tensors, state)), every=3))
    assert [state["next"] for _, state in saved] == [4, 5], "every 3 steps, and at the interruption"
    assert stopped.events[-2:] == ["step 4", "save 4"] and [row["tick"] for row in logged] == [1.0, 2.0, 3.0, 4.0]
    tensors, state = saved[-1]
    assert torch.equal(tensors["weight"], torch.tensor([4.0]))
    assert signal.getsignal(signal.SIGINT) is handler, "the loop put Ctrl-C's handler back"

    # Resuming loads the checkpoint before the first step and goes on to the total.
    saved.clear()
    resumed = FakeLearner(10)
    rows = run(resumed, checkpoints=Checkpointing(save=lambda tensors, state: saved.append((tensors, state)), every=3, resume=(tensors, state)))
    assert resumed.events[0] == "load 4" and resumed.events[1] == "step 5"
    assert [row["tick"] for row in rows] == [float(i) for i in range(5, 11)] and resumed.completed == resumed.total
    assert [state["next"] for _, state in saved] == [7, 10, 11]
    resumed_at_start = FakeLearner(10)
    saved.clear()
    run(resumed_at_start, checkpoints=Checkpointing(save=keep, every=3, resume=(tensors, state), at_start=keep))
    assert resumed_at_start.events[:2] == ["load 4", "step 5"] and [state["next"] for _, state in saved] == [7, 10, 11]

    # Without checkpoints nothing is saved (the learner's state is never asked for).
    plain = FakeLearner(10)
    rows = run(plain)
    assert len(rows) == 10 and plain.events == [f"step {i}" for i in range(1, 11)]
