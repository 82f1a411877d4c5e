"""Checkpoints hold the whole training state: BC, DAgger and tabular IRL resumed from one end bit
for bit where an uninterrupted run ends; PPO's round trip restores networks, optimiser,
normalisers and random generators exactly, and GCL's reward learner, saved in PPO's checkpoint,
goes on exactly as the original would; Ctrl-C stops at an update boundary with a checkpoint saved.
(PPO itself does not resume bit for bit: its environments start new episodes.)"""

from __future__ import annotations

import os
import signal
from collections import deque
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from support import DATASETS

import imitation.envs  # noqa: F401  (registers the ids)
from imitation.algorithms.bc import BCConfig, policy_options, train_bc
from imitation.algorithms.dagger import DAggerConfig, train_dagger
from imitation.algorithms.gcl import GCLConfig, GuidedCostLearning
from imitation.algorithms.maxent_irl import Dynamics, MaxEntIRLConfig, state_visitation, train_maxent_irl
from imitation.algorithms.ppo import PPOConfig, Rollout, RewardScaler, ppo_checkpoint, ppo_defaults, restore_ppo_checkpoint, train_ppo
from imitation.checkpoints import Checkpointing, TrainingInterrupted, snapshot
from imitation.data.loader import load_transitions, transitions_to_torch
from imitation.data.store import DemoFile
from imitation.envs.tabular import gridworld
from imitation.errors import ImitationError
from imitation.experts.scripted import cartpole
from imitation.experts.tabular import soft_optimal_policy
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
    whole = train_bc(fresh_policy(demo), data, validation, CONFIG, progress=False)

    saved = []

    def press_ctrl_c_during_epoch_5(policy) -> float:
        os.kill(os.getpid(), signal.SIGINT)  # deferred to the end of the epoch
        return 0.0

    def save(tensors, state) -> None:
        save_checkpoint(tmp_path, tensors, {"trainer": state})  # through the files, as a run does
        saved.append(state["epoch"])

    with pytest.raises(TrainingInterrupted, match="BC stopped after epoch 5 of 12"):
        train_bc(fresh_policy(demo), data, validation, CONFIG, evaluate=press_ctrl_c_during_epoch_5, evaluate_every=5, progress=False,
                 checkpoints=Checkpointing(save=save, every=2))
    assert saved == [3, 5, 6], "every 2 epochs, and at the interruption"
    tensors, state = read_checkpoint(tmp_path)
    torch.manual_seed(123)  # the resumed process's generators start elsewhere: the checkpoint must set them
    resumed = train_bc(fresh_policy(demo), data, validation, CONFIG, progress=False, checkpoints=Checkpointing(save=lambda *a: None, resume=(tensors, state["trainer"])))
    assert [row["epoch"] for row in resumed.history] == list(range(1, 13))
    assert resumed.best_epoch == whole.best_epoch
    assert [row["validation_loss"] for row in resumed.history] == [row["validation_loss"] for row in whole.history]
    for name, tensor in whole.policy.state_dict().items():
        assert torch.equal(resumed.policy.state_dict()[name], tensor), name


def test_ppo_checkpoint_round_trip_is_exact(demos) -> None:
    demo, data, _ = demos
    policy = make_policy(demo.observation_space, demo.action_space, normalize_observations=True)
    optimizer = torch.optim.Adam(policy.parameters(), lr=1e-3, eps=1e-5)
    scaler = RewardScaler(4, 0.99)
    for _ in range(3):  # some optimiser, normaliser and scaler state
        policy.update_normalizer(data.observations[:64])
        loss = policy.value(policy.encode(data.observations[:64])).pow(2).mean()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        scaler(np.random.default_rng(0).normal(size=4), np.zeros(4, dtype=bool))
    history = [{"step": 1.0, "return": float("nan")}]
    checkpoint = ppo_checkpoint(7, 1792, 0.5, 12.5, policy=policy, optimizer=optimizer, reward_scaler=scaler, history=history,
                                recent_returns=deque([1.0, 2.0]), recent_optimised_returns=deque([3.0]), timers={"env": 1.0})
    expected_next = (torch.rand(3), np.random.random(3))

    torch.manual_seed(99)
    copy = make_policy(demo.observation_space, demo.action_space, normalize_observations=True)
    copy_optimizer = torch.optim.Adam(copy.parameters(), lr=1e-3, eps=1e-5)
    copy_scaler = RewardScaler(4, 0.99)
    copy_history, returns, optimised, timers = [], deque(maxlen=20), deque(maxlen=20), {"env": 0.0}
    counters = restore_ppo_checkpoint(checkpoint, policy=copy, optimizer=copy_optimizer, reward_scaler=copy_scaler, history=copy_history,
                                      recent_returns=returns, recent_optimised_returns=optimised, timers=timers)
    assert counters == (7, 1792, 0.5, 12.5)
    for name, tensor in policy.state_dict().items():
        assert torch.equal(copy.state_dict()[name], tensor), name
    assert len(copy_optimizer.state) == len(optimizer.state) > 0
    for mine, theirs in zip(optimizer.state.values(), copy_optimizer.state.values()):
        assert all(torch.equal(mine[key], theirs[key]) for key in mine)
    assert all(torch.equal(copy_scaler.stats.state_dict()[name], t) for name, t in scaler.stats.state_dict().items())
    assert list(returns) == [1.0, 2.0] and list(optimised) == [3.0] and timers == {"env": 1.0} and np.isnan(copy_history[0]["return"])
    assert torch.equal(torch.rand(3), expected_next[0]) and np.array_equal(np.random.random(3), expected_next[1])

    with pytest.raises(ImitationError, match="the checkpoint does not fit this PPO run"):
        restore_ppo_checkpoint(({}, {}), policy=copy, optimizer=copy_optimizer, reward_scaler=None, history=[],
                               recent_returns=deque(), recent_optimised_returns=deque(), timers={})


def test_ppo_resumes_to_the_requested_total() -> None:
    config = PPOConfig(env_id="CartPole-v1", total_steps=2560, n_envs=2, n_steps=128, seed=0, device="cpu")
    saved = []
    train_ppo(config, progress=False, checkpoints=Checkpointing(save=lambda tensors, state: saved.append((tensors, state)), every=3))
    assert [state["update"] for _, state in saved] == [3, 6, 9], "every 3 of 10 updates, not after the last"
    resumed = train_ppo(config, progress=False, checkpoints=Checkpointing(save=lambda *a: None, resume=saved[0]))
    assert resumed.steps == 2560 and [row["step"] for row in resumed.history] == [256.0 * (i + 1) for i in range(10)]
    assert resumed.history[:3] == saved[0][1]["history"]


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

    def run(folder: str, **options):
        torch.manual_seed(0)
        policy = make_policy(env.observation_space, env.action_space, **policy_options(config.bc))
        return train_dagger(env, cartpole, policy, config, round_dir=tmp_path / folder, env_id="CartPole-v1", **options)

    whole = run("whole")
    saved = []
    with pytest.raises(TrainingInterrupted, match="DAgger stopped after round 1 of 3"):
        run("stopped", evaluate=press_ctrl_c, checkpoints=Checkpointing(save=lambda *checkpoint: saved.append(through_files(tmp_path / "ckpt", checkpoint))))
    assert [state["round"] for _, state in saved] == [2] and saved[0][1]["round_files"] == ["round-01.mcap"]
    recorded = (tmp_path / "stopped" / "round-01.mcap").stat()
    torch.manual_seed(123)  # the resumed process's generators start elsewhere: the checkpoint and the seeds must set them
    resumed = run("stopped", checkpoints=Checkpointing(save=lambda *a: None, resume=saved[0]))
    assert (tmp_path / "stopped" / "round-01.mcap").stat().st_mtime_ns == recorded.st_mtime_ns, "round 1 is reused, not recorded again"
    assert [path.name for path in resumed.round_files] == ["round-01.mcap", "round-02.mcap", "round-03.mcap"]
    for column in ("beta", "expert_labels", "rollout_return", "validation_loss"):
        np.testing.assert_array_equal([row[column] for row in resumed.history], [row[column] for row in whole.history], err_msg=column)
    for name, tensor in whole.policy.state_dict().items():
        assert torch.equal(resumed.policy.state_dict()[name], tensor), name
    with pytest.raises(ImitationError, match="the checkpoint does not fit this DAgger run"):
        run("other", checkpoints=Checkpointing(save=lambda *a: None, resume=({}, {})))


def test_tabular_irl_resumed_from_a_ctrl_c_checkpoint_ends_exactly_where_an_uninterrupted_run_does(tmp_path: Path) -> None:
    mdp = gridworld()
    target = state_visitation(Dynamics.of(mdp.transition), mdp.initial, soft_optimal_policy(mdp), horizon=mdp.horizon, discount=1.0)
    config = MaxEntIRLConfig(iterations=30, tolerance=0.0, hidden_sizes=[8])

    def model():
        torch.manual_seed(0)
        return make_reward_model(gym.spaces.Discrete(mdp.n_states), gym.spaces.Discrete(mdp.n_actions), feature_table=mdp.features, hidden_sizes=[8])

    whole = train_maxent_irl(mdp, target, model(), config)
    saved = []

    def log(row) -> None:
        if row["iteration"] == 7:
            press_ctrl_c()

    with pytest.raises(TrainingInterrupted, match="mce IRL stopped after iteration 7 of 30"):
        train_maxent_irl(mdp, target, model(), config, log=log, checkpoints=Checkpointing(save=lambda *c: saved.append(through_files(tmp_path, c)), every=5))
    assert [state["iteration"] for _, state in saved] == [6, 8], "every 5 iterations, and at the interruption"
    resumed = train_maxent_irl(mdp, target, model(), config, checkpoints=Checkpointing(save=lambda *a: None, resume=saved[-1]))
    assert [row["iteration"] for row in resumed.history] == list(range(1, 31))
    assert [row["loss"] for row in resumed.history] == [row["loss"] for row in whole.history]
    for name, tensor in whole.reward_model.state_dict().items():
        assert torch.equal(resumed.reward_model.state_dict()[name], tensor), name
    with pytest.raises(ImitationError, match="the checkpoint does not fit this tabular IRL run"):
        train_maxent_irl(mdp, target, model(), config, checkpoints=Checkpointing(save=lambda *a: None, resume=({}, {})))


GCL_ENV = "imitation/CartPoleFixedHorizon-v0"


def gcl_learner(seed: int, updates: int = 3) -> GuidedCostLearning:
    env = gym.make(GCL_ENV)
    demos = transitions_to_torch(load_transitions(DATASETS / "CartPoleFixedHorizon-v0.mcap", next_observations=True))
    torch.manual_seed(seed)
    reward = make_reward_model(env.observation_space, env.action_space, hidden_sizes=[16], normalize_observations=True)
    return GuidedCostLearning(reward, demos, GCLConfig(warmup_steps=20, reward_steps=4, batch_size=64), updates=updates)


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
    original = gcl_learner(seed=0)
    original(demo_rollout(0), policy)
    tensors, state = through_files(tmp_path, original.checkpoint())
    copy = gcl_learner(seed=1)  # other initial weights: the checkpoint must set them
    copy.restore((tensors, state))
    assert torch.equal(copy(demo_rollout(64), policy), original(demo_rollout(64), policy))
    for name, tensor in original.reward.state_dict().items():
        assert torch.equal(copy.reward.state_dict()[name], tensor), name
    assert torch.equal(copy.pool.observations, original.pool.observations) and len(copy.pool.log_mass) == 128 and len(copy.samplers) == len(original.samplers) > 0
    assert torch.equal(copy.generator.get_state(), original.generator.get_state())
    assert copy.history == original.history and len(copy.history) == 2
    assert torch.equal(copy.log_partition, original.log_partition)
    assert len(copy.optimizer.state) == len(original.optimizer.state) > 0
    for mine, theirs in zip(original.optimizer.state.values(), copy.optimizer.state.values()):
        assert all(torch.equal(mine[key], theirs[key]) for key in mine)


def test_gcl_learner_rides_in_ppo_checkpoints_and_resumes_with_them() -> None:
    config = PPOConfig(env_id=GCL_ENV, total_steps=4 * 256, **ppo_defaults(GCL_ENV) | {"device": "cpu"})
    saved = []
    train_ppo(config, rollout_rewards=gcl_learner(seed=0, updates=4), progress=False,
              checkpoints=Checkpointing(save=lambda tensors, state: saved.append((tensors, state)), every=2))
    tensors, state = saved[0]
    assert state["update"] == 2 and len(state["learner"]["history"]) == 2 and tensors["learner.pool.log_mass"].shape == (512,)
    resumed = gcl_learner(seed=1, updates=4)
    train_ppo(config, rollout_rewards=resumed, progress=False, checkpoints=Checkpointing(save=lambda *a: None, resume=saved[0]))
    assert len(resumed.history) == 4 and resumed.history[:2] == state["learner"]["history"]
    assert len(resumed.pool.log_mass) == 4 * 256 and len(resumed.samplers) == 4, "the pool kept the rollouts from before the interruption"
    with pytest.raises(ImitationError, match="the checkpoint does not fit this PPO run"):
        train_ppo(config, rollout_rewards=gcl_learner(seed=1), progress=False,
                  checkpoints=Checkpointing(save=lambda *a: None, resume=(tensors, {k: v for k, v in state.items() if k != "learner"})))
