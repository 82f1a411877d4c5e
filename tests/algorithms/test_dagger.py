"""DAgger: β schedules, expert labels on every visited state, rounds written as MCAP files."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from imitation.algorithms.bc import BCConfig, policy_options
from imitation.algorithms.dagger import DAgger, DAggerConfig, beta_for_round, collect_round
from imitation.data.dataset import DemoDataset
from imitation.data.mcap.reader import DemoFile
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
    episodes = collect_round(LastAction(), learner, expert, beta=0.3, episodes=20, seed=0, rng=np.random.default_rng(0), metadata={})
    taken = np.concatenate([episode.observations[1:] for episode in episodes])
    assert len(taken) == 2000 and abs(taken.mean() - 0.3) < 4 * np.sqrt(0.3 * 0.7 / 2000)
    assert sum(episode.metadata["expert_steps"] for episode in episodes) == taken.sum()
    assert all((episode.actions == 1).all() for episode in episodes)


def test_collected_episodes_say_how_they_ended_and_which_seed_reset_them() -> None:
    """CartPole under the learner alone falls (terminated); LastAction runs into its time limit (truncated)."""
    rng = np.random.default_rng(0)
    fallen = collect_round(gym.make("CartPole-v1"), lambda observation: 0, cartpole, beta=0.0, episodes=2, seed=7, rng=rng, metadata={"round": 3})
    assert [(e.terminated, e.truncated) for e in fallen] == [(True, False)] * 2
    assert [e.metadata for e in fallen] == [{"round": 3, "seed": 7, "expert_steps": 0}, {"round": 3, "seed": 8, "expert_steps": 0}]
    (timed_out,) = collect_round(LastAction(), lambda observation: 0, lambda observation: 1, beta=1.0, episodes=1, seed=0, rng=rng, metadata={})
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
