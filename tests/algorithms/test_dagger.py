"""DAgger: β schedules, expert labels on every visited state, rounds written as MCAP files."""

from __future__ import annotations

import copy
import shutil

import gymnasium as gym
import numpy as np
import pytest
import torch

from imitation.algorithms.bc import BCConfig, bc_loss, policy_options
from imitation.algorithms.dagger import DAgger, DAggerConfig, beta_for_round, collect_round
from imitation.checkpoints import snapshot
from imitation.data.dataset import DemoDataset
from imitation.data.loader import load_transitions, split_episodes, transitions_to_torch
from imitation.data.mcap.reader import DemoFile
from imitation.data.mcap.writer import write_episodes
from imitation.errors import ConfigError, ImitationError
from imitation.evaluation.policy import evaluate_policy
from imitation.experts.scripted import cartpole
from imitation.jobs.loop import run
from imitation.policies import SingleObservationPolicy, make_policy


def test_beta_schedules() -> None:
    linear = DAggerConfig(rounds=4, beta_schedule="linear")
    assert [beta_for_round(i, linear) for i in range(1, 5)] == [1.0, 0.75, 0.5, 0.25]
    exponential = DAggerConfig(rounds=4, beta_schedule="exponential", beta_decay=0.5)
    assert [beta_for_round(i, exponential) for i in range(1, 5)] == [1.0, 0.5, 0.25, 0.125]


def test_every_visited_state_is_labelled_by_the_expert() -> None:
    env = gym.make("CartPole-v1")
    always_left = lambda observation: 0  # noqa: E731
    rng = np.random.default_rng(0)
    for beta, expected_expert_share in ((0.0, 0.0), (1.0, 1.0)):
        (episode,) = collect_round(env, always_left, cartpole, beta=beta, episodes=1, seed=4, rng=rng, metadata={})
        labels = [cartpole(observation) for observation in episode.observations[:-1]]
        assert episode.actions.tolist() == labels
        assert episode.metadata["expert_steps"] == round(expected_expert_share * len(episode))
    # The learner alone falls over fast; the expert alone balances to the limit.
    assert len(collect_round(env, always_left, cartpole, beta=0.0, episodes=1, seed=4, rng=rng, metadata={})[0]) < 50


class LastAction(gym.Env):
    """Observes the action it was last given (2 before the first): shows who drove each step."""

    observation_space = gym.spaces.Discrete(3)
    action_space = gym.spaces.Discrete(2)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.t = 0
        return 2, {}

    def step(self, action):
        self.t += 1
        return int(action), 0.0, False, self.t >= 100, {}


def test_an_intermediate_beta_lets_the_expert_act_on_that_share_of_steps() -> None:
    """π_i = β π* + (1 - β) π̂_i at each step: with β = 0.3 over 2,000 steps the expert's share
    of the actions taken is 0.3 within four binomial standard deviations (0.041), and the
    stored actions are the expert's labels throughout."""
    expert, learner = (lambda observation: 1), (lambda observation: 0)
    episodes = collect_round(
        LastAction(), learner, expert, beta=0.3, episodes=20, seed=0, rng=np.random.default_rng(0), metadata={}
    )
    taken = np.concatenate([episode.observations[1:] for episode in episodes])
    assert len(taken) == 2000 and abs(taken.mean() - 0.3) < 4 * np.sqrt(0.3 * 0.7 / 2000)
    assert sum(episode.metadata["expert_steps"] for episode in episodes) == taken.sum()
    assert all((episode.actions == 1).all() for episode in episodes)


def test_collected_episodes_say_how_they_ended_and_which_seed_reset_them() -> None:
    """CartPole under the learner alone falls (terminated); LastAction runs into its time limit (truncated)."""
    rng = np.random.default_rng(0)
    fallen = collect_round(
        gym.make("CartPole-v1"), lambda observation: 0, cartpole, beta=0.0, episodes=2, seed=7, rng=rng, metadata={"round": 3}
    )
    assert [(e.terminated, e.truncated) for e in fallen] == [(True, False)] * 2
    assert [e.metadata for e in fallen] == [
        {"round": 3, "seed": 7, "expert_steps": 0},
        {"round": 3, "seed": 8, "expert_steps": 0},
    ]
    (timed_out,) = collect_round(
        LastAction(), lambda observation: 0, lambda observation: 1, beta=1.0, episodes=1, seed=0, rng=rng, metadata={}
    )
    assert (timed_out.terminated, timed_out.truncated) == (False, True) and timed_out.metadata["expert_steps"] == 100


def test_dagger_rounds_are_reloadable_demo_files(tmp_path) -> None:
    env = gym.make("CartPole-v1")
    config = DAggerConfig(rounds=3, episodes_per_round=2, seed=0, bc=BCConfig(epochs=15, patience=15, hidden_sizes=[64, 64]))
    policy = make_policy(env.observation_space, env.action_space, **policy_options(config.bc))
    dagger = DAgger(env, cartpole, policy, config, round_dir=tmp_path / "rounds", env_id="CartPole-v1")
    history = run(dagger)
    assert [path.name for path in dagger.files] == ["round-01.mcap", "round-02.mcap", "round-03.mcap"]
    aggregate = DemoDataset(dagger.files)
    assert len(aggregate) == 6
    assert [DemoFile(path).user_metadata["beta"] for path in dagger.files] == pytest.approx([1.0, 2 / 3, 1 / 3])
    assert [row["expert_labels"] for row in history] == np.cumsum(
        [sum(f.length for f in DemoFile(path).episodes) for path in dagger.files]
    ).tolist()
    assert evaluate_policy(SingleObservationPolicy(dagger.policy), env, episodes=3, seed=0)["mean_return"] >= 200


@pytest.mark.parametrize(("beta_decay", "valid"), [(0.0, True), (1.0, True), (-0.01, False), (1.01, False)])
def test_the_exponential_schedules_decay_must_lie_in_the_closed_unit_interval(beta_decay: float, valid: bool) -> None:
    config = DAggerConfig(beta_schedule="exponential", beta_decay=beta_decay)
    if valid:
        config.validate()
    else:
        with pytest.raises(ConfigError, match=r"^beta_decay must be in \[0, 1\]"):
            config.validate()


class FallsAtTheLimit(gym.Env):
    """Falls over on its third and last step: terminated and truncated at once."""

    observation_space = gym.spaces.Discrete(2)
    action_space = gym.spaces.Discrete(2)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.t = 0
        return 0, {}

    def step(self, action):
        self.t += 1
        return 0, 0.0, self.t >= 3, self.t >= 3, {}


def test_an_episode_that_falls_on_its_time_limit_counts_as_terminated_not_truncated() -> None:
    """The final state is terminal either way: it must not be bootstrapped past."""
    (episode,) = collect_round(
        FallsAtTheLimit(), None, lambda observation: 0, beta=1.0, episodes=1, seed=0, rng=np.random.default_rng(0), metadata={}
    )
    assert (len(episode), episode.terminated, episode.truncated) == (3, True, False)


class Coin(gym.Env):
    """A fresh random number in [-1, 1] every step; the expert's action is whether it is positive,
    and the reward is the action taken, so a round's rewards show what the mixture did."""

    observation_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
    action_space = gym.spaces.Discrete(2)
    dt = 0.05

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.t = 0
        return self._observation(), {}

    def step(self, action):
        self.t += 1
        return self._observation(), float(action), False, self.t >= 5, {}

    def _observation(self) -> np.ndarray:
        return self.np_random.uniform(-1.0, 1.0, (1,)).astype(np.float32)


def coin_expert(observation) -> int:
    return int(observation[0] > 0)


def coin_dagger(round_dir, *, demos=(), evaluate=None, seed: int = 1) -> DAgger:
    """Two rounds of ten 5-step episodes (β = 1, then 0.5); BC of one short epoch, which leaves the
    learner far from the expert, so that its own actions show."""
    torch.manual_seed(0)
    env = Coin()
    bc = BCConfig(
        epochs=1,
        patience=1,
        batch_size=16,
        epoch_samples=32,
        hidden_sizes=[8],
        validation_fraction=0.5,
        seed=seed,
        device="cpu",
    )
    config = DAggerConfig(rounds=2, episodes_per_round=10, seed=seed, bc=bc)
    policy = make_policy(env.observation_space, env.action_space, **policy_options(bc))
    return DAgger(env, coin_expert, policy, config, round_dir=round_dir, env_id="Coin-v0", demos=demos, evaluate=evaluate)


def greedy_actions(policy, observations: np.ndarray) -> np.ndarray:
    greedy = SingleObservationPolicy(copy.deepcopy(policy), deterministic=True)  # a copy: this one is put in eval mode
    return np.array([greedy(observation) for observation in observations])


def test_dagger_rounds_mix_expert_and_greedy_learner_by_the_generator_and_record_how(tmp_path) -> None:
    """Round 1 (β = 1, no demos) is the expert's alone and draws no random number; in round 2
    (β = 0.5) step t is the expert's exactly when the t-th draw of default_rng(seed) is below β,
    and the other steps take the round-1 learner's greedy action. Each round's file and episodes
    say which round, β, reset seed (seed·100,000 + round·1,000 + i) and how many steps the
    expert drove; the round directory is created with its parents; the row's validation loss
    is the kept policy's loss on the held-out episodes (split by the seed), and its observation
    normaliser is fitted on the training episodes only. A learner restored from round 1's
    checkpoint records the same round 2."""
    evaluated = []
    dagger = coin_dagger(tmp_path / "run" / "rounds", evaluate=lambda policy: evaluated.append(policy) or 7.0)
    first = dagger.step()
    round_one = DemoFile(tmp_path / "run" / "rounds" / "round-01.mcap")
    assert (round_one.source, round_one.dt, round_one.user_metadata) == ("dagger round 1", 0.05, {"round": 1, "beta": 1.0, "mode": "label"})
    assert [facts.metadata for facts in round_one.episodes] == [
        {"round": 1, "beta": 1.0, "seed": 101_000 + i, "expert_steps": 5} for i in range(10)
    ]
    episodes = round_one.read_episodes()
    assert first["rollout_return"] == pytest.approx(np.mean([episode.rewards.sum() for episode in episodes]))
    assert evaluated == [dagger.policy] and first["return"] == 7.0
    assert dagger.progress(first) == {"beta": "1.00", "labels": "50", "ret": "7.0"}
    train_ids, validation_ids = split_episodes(10, validation_fraction=0.5, seed=1)
    held_out = transitions_to_torch(load_transitions(round_one.path, episodes=validation_ids, next_observations=False))
    with torch.no_grad():
        expected_loss, _ = bc_loss(dagger.policy, held_out, BCConfig(l2_coef=0.0))
    assert first["validation_loss"] == pytest.approx(expected_loss.item(), rel=1e-5)
    seen = np.concatenate([episodes[k].observations[:-1] for k in train_ids])
    np.testing.assert_allclose(dagger.policy.obs_rms.mean.numpy(), seen.mean(0), rtol=1e-5)

    checkpoint = snapshot(*dagger.state_dict())
    learner = copy.deepcopy(dagger.policy)
    second = dagger.step()
    round_two = DemoFile(tmp_path / "run" / "rounds" / "round-02.mcap").read_episodes()
    expert_drove = np.random.default_rng(1).random(50).reshape(10, 5) < 0.5
    assert [episode.metadata["expert_steps"] for episode in round_two] == expert_drove.sum(1).tolist()
    assert [episode.metadata["seed"] for episode in round_two] == [102_000 + i for i in range(10)]
    for episode, expert in zip(round_two, expert_drove):
        observations = episode.observations[:-1]
        assert episode.actions.tolist() == [coin_expert(o) for o in observations]
        taken = np.where(expert, episode.actions, greedy_actions(learner, observations))
        np.testing.assert_array_equal(episode.rewards, taken)
    assert dagger.progress(second) == {"beta": "0.50", "labels": "100", "ret": "7.0"}

    (tmp_path / "resumed").mkdir()
    shutil.copy(tmp_path / "run" / "rounds" / "round-01.mcap", tmp_path / "resumed")
    resumed = coin_dagger(tmp_path / "resumed")
    resumed.load_state_dict(checkpoint)
    resumed.step()
    again = DemoFile(tmp_path / "resumed" / "round-02.mcap").read_episodes()
    for episode, original in zip(again, round_two, strict=True):
        np.testing.assert_array_equal(episode.rewards, original.rewards)


def test_dagger_checkpoints_next_round_must_lie_between_one_and_rounds_plus_one(tmp_path) -> None:
    """1 (nothing done yet) and rounds + 1 (finished) load; outside that range is refused, naming the counter."""
    dagger = coin_dagger(tmp_path / "rounds")
    tensors, state = dagger.state_dict()
    for next_round, done in ((1, False), (3, True)):
        restored = coin_dagger(tmp_path / "rounds")
        restored.load_state_dict((tensors, state | {"round": next_round}))
        assert (restored.completed, restored.done) == (next_round - 1, done)
    for next_round in (0, 4):
        with pytest.raises(ImitationError, match=f"the checkpoint's next round is {next_round}, outside 1..3"):
            coin_dagger(tmp_path / "rounds").load_state_dict((tensors, state | {"round": next_round}))


def test_dagger_with_demos_clones_them_and_lets_the_clone_drive_from_round_one(tmp_path) -> None:
    """The demos stand for the expert-only first round, so round i runs at β_{i+1} (linear, R = 2:
    0.5, then 0): round 1's step t is the expert's exactly when the t-th draw is below 0.5, with
    the learner cloned from the demos driving the rest, and round 2 is the learner's alone. BC
    needs no s': an episode's final observation is never read, so a damaged one (NaN, as a
    recording may end) stops nothing."""
    env = Coin()
    demos = collect_round(env, None, coin_expert, beta=1.0, episodes=4, seed=50, rng=np.random.default_rng(0), metadata={})
    for episode in demos:
        episode.observations[-1] = np.nan
    path = write_episodes(
        tmp_path / "demos.mcap",
        demos,
        env_id="Coin-v0",
        observation_space=env.observation_space,
        action_space=env.action_space,
        finite_only=False,
    )
    dagger = coin_dagger(tmp_path / "rounds", demos=[path])
    run(dagger)
    rounds = [DemoFile(tmp_path / "rounds" / f"round-0{i}.mcap") for i in (1, 2)]
    assert [file.user_metadata["beta"] for file in rounds] == [0.5, 0.0]
    expert_drove = np.random.default_rng(1).random(50).reshape(10, 5) < 0.5
    assert 0 < expert_drove.sum() < 50
    assert [episode.metadata["expert_steps"] for episode in rounds[0].read_episodes()] == expert_drove.sum(1).tolist()
    assert [episode.metadata["expert_steps"] for episode in rounds[1].read_episodes()] == [0] * 10
