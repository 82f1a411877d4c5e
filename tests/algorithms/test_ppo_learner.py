"""The PPO learner around `ppo_update`: each update is GAE over the rollout followed by
`ppo_update` on the flattened rollout (checked against a reference written from the notes), its
logged row is the hand computation of every field, learned rewards are kept as the notes say, and
its checkpoint round trips. Tiny rollouts (2 envs × 8 steps of a 2-D point) keep each test fast."""

from __future__ import annotations

import copy
import math
import multiprocessing
import re
import time
import warnings

import gymnasium as gym
import numpy as np
import pytest
import torch
from torch.distributions import Normal, kl_divergence

from imitation.algorithms.ppo import (
    PPO,
    PPOConfig,
    RewardScaler,
    UpdateBatch,
    check_finite_step,
    ppo_update,
)
from imitation.algorithms.advantages import compute_gae
from imitation.envs.vector import make_vector_env
from imitation.checkpoints import snapshot, unprefixed
from imitation.envs.rollout import Rollout
from imitation.errors import ConfigError, ImitationError
from imitation.policies import ActorCritic, PolicyConfig


class Drift(gym.Env):
    """A point in the plane pushed by the action (2-D Box, or 3 discrete moves), rewarded −|x|².
    Each copy's odd episodes terminate after 3 steps; its even ones are cut by the 4-step time
    limit: an 8-step rollout has both kinds of episode end at known steps."""

    observation_space = gym.spaces.Box(-np.inf, np.inf, (2,), np.float32)

    def __init__(self, discrete: bool = False) -> None:
        self.action_space = gym.spaces.Discrete(3) if discrete else gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
        self.episodes = 0

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.episodes += 1
        self.t = 0
        self.x = self.np_random.uniform(-1.0, 1.0, 2).astype(np.float32)
        return self.x.copy(), {}

    def step(self, action):
        self.t += 1
        push = (float(action) - 1.0) * np.ones(2) if self.action_space.shape == () else np.clip(action, -1.0, 1.0)
        self.x = (self.x + 0.5 * push).astype(np.float32)
        return self.x.copy(), float(-(self.x**2).sum()), self.episodes % 2 == 1 and self.t == 3, False, {}


gym.register("TestPPODrift-v0", entry_point=Drift, max_episode_steps=4)
gym.register("TestPPODriftDiscrete-v0", entry_point=Drift, kwargs={"discrete": True}, max_episode_steps=4)

N_ENVS, N_STEPS, UPDATES = 2, 8, 3


def tiny_config(**options) -> PPOConfig:
    settings = dict(
        env_id="TestPPODrift-v0",
        total_steps=UPDATES * N_ENVS * N_STEPS,
        n_envs=N_ENVS,
        n_steps=N_STEPS,
        batch_size=4,
        n_epochs=2,
        hidden_sizes=[8],
        learning_rate=0.01,
        gamma=0.9,
        gae_lambda=0.8,
        seed=0,
        device="cpu",
    )
    return PPOConfig(**settings | options)


def learned_reward(rollout: Rollout) -> torch.Tensor:
    """A stand-in for a reward model's output: r(s, a) = 1 + s·a + 0.1 t, another scale from the env's."""
    steps = torch.arange(N_STEPS, dtype=torch.float32)[:, None]
    actions = rollout.env_actions if rollout.env_actions.ndim == 3 else rollout.env_actions[..., None]
    return 1.0 + (rollout.observations * actions).sum(-1) + 0.1 * steps


def reference_batch(policy: ActorCritic, rollout: Rollout, rewards: torch.Tensor, config: PPOConfig) -> UpdateBatch:
    """The update's batch from the notes, with π_k = `policy` (the one that collected the rollout):
    δ_t = r_t + γ (1 - term_t) V(s_{t+1}) - V(s_t) with s_{t+1} the state that followed step t
    (a truncated episode's true final state), then GAE(γ, λ), R = Â + V, flattened step-major."""
    steps, envs = rewards.shape
    flat = lambda x: x.reshape(steps * envs, *x.shape[2:])  # noqa: E731
    with torch.no_grad():
        features = flat(rollout.observations).float()
        values = policy.value(features)
        next_values = policy.value(flat(rollout.next_observations).float())
        out = policy.action_head(policy.actor_trunk(features))
    advantages, returns = compute_gae(
        rewards,
        values.reshape(steps, envs),
        next_values.reshape(steps, envs),
        rollout.terminated,
        rollout.truncated,
        gamma=config.gamma,
        gae_lambda=config.gae_lambda,
    )
    return UpdateBatch(
        inputs=features,
        actions=flat(rollout.actions),
        log_probs=flat(rollout.log_probs),
        advantages=flat(advantages),
        returns=flat(returns),
        values=values,
        parameters=out if policy.is_continuous else torch.log_softmax(out, -1),
        old_log_std=policy.log_std.detach().clone() if policy.is_continuous else None,
    )


def episode_returns(rewards: torch.Tensor, rollout: Rollout, running: np.ndarray) -> list[float]:
    """Undiscounted returns of the episodes that end in the rollout, in the order they end
    (`running`: each env's sum so far, carried from rollout to rollout)."""
    finished = []
    ends = (rollout.terminated | rollout.truncated).numpy()
    for t, step_rewards in enumerate(rewards.double().numpy()):
        running += step_rewards
        for i in np.flatnonzero(ends[t]):
            finished.append(float(running[i]))
            running[i] = 0.0
    return finished


ROW_KEYS = {
    "step",
    "return",
    "optimised_return",
    "policy_loss",
    "value_loss",
    "entropy",
    "kl",
    "kl_beta",
    "clip_fraction",
    "explained_variance",
    "learning_rate",
    "early_stop",
    "steps_per_second",
    "seconds_env",
    "seconds_inference",
    "seconds_update",
}

SETTINGS = {
    "categorical, clip, the env's reward": dict(env_id="TestPPODriftDiscrete-v0", objective="clip"),
    # kl_target far above the KL one update reaches: β halves after each update.
    "gaussian, kl, a learned bfloat16 reward, scaled": dict(
        objective="kl", kl_target=1.0, kl_beta_init=0.8, normalize_rewards=True
    ),
}


@pytest.mark.parametrize("setting", SETTINGS)
def test_each_update_is_gae_then_the_minibatch_epochs_and_its_row_is_computed_by_hand(setting: str) -> None:
    config = tiny_config(**SETTINGS[setting])
    learned = "learned" in setting
    learner = PPO(config)
    # The reference: the same start, Adam on the same annealed schedule, β and the reward scaler by the notes.
    reference = copy.deepcopy(learner.policy)
    optimizer = torch.optim.Adam(reference.parameters(), lr=config.learning_rate, eps=1e-5)
    scaler = RewardScaler(N_ENVS, config.gamma) if config.normalize_rewards else None
    beta = config.kl_beta_init
    true_running, optimised_running, true_returns, optimised_returns = np.zeros(N_ENVS), np.zeros(N_ENVS), [], []
    try:
        for update in range(2):
            assert learner.position() == f"update {update}/{UPDATES}, at step {update * 16} of 48"
            rollout = learner.collect_rollout()
            assert rollout.terminated.any() and rollout.truncated.any()
            # A learned reward may come in any float dtype; what is optimised is its float32 value.
            rewards = learned_reward(rollout).to(torch.bfloat16) if learned else rollout.env_rewards.clone()
            optimised = rewards.float()
            true_returns += episode_returns(rollout.env_rewards, rollout, true_running)
            optimised_returns += episode_returns(optimised, rollout, optimised_running)
            generator = torch.get_rng_state()
            row = learner.update(rollout, rewards)

            scaled = optimised
            if scaler is not None:
                ends = (rollout.terminated | rollout.truncated).numpy()
                scaled = torch.tensor(
                    np.stack([scaler(r, ends[t]) for t, r in enumerate(optimised.numpy())]), dtype=torch.float32
                )
            batch = reference_batch(reference, rollout, scaled, config)
            learning_rate = (1.0 - update / UPDATES) * config.learning_rate
            optimizer.param_groups[0]["lr"] = learning_rate
            torch.set_rng_state(generator)  # the same minibatches
            measured = ppo_update(reference, optimizer, batch, config, beta)
            for (name, mine), theirs in zip(learner.policy.named_parameters(), reference.parameters()):
                assert torch.allclose(mine, theirs, atol=1e-5), (update, name)

            expected = {
                "step": 16.0 * (update + 1),
                "return": np.mean(true_returns),
                "optimised_return": np.mean(optimised_returns),
                "policy_loss": measured.policy_loss,
                "value_loss": measured.value_loss,
                "entropy": measured.entropy,
                "clip_fraction": measured.clip_fraction,
                "learning_rate": learning_rate,
                "early_stop": 0.0,
                "explained_variance": 1.0 - float(torch.var(batch.returns - batch.values) / torch.var(batch.returns)),
            }
            if config.objective == "kl":
                # The exact mean KL from π_k to the updated policy (old first); β halves below δ/1.5.
                with torch.no_grad():
                    new_out = reference.action_head(reference.actor_trunk(batch.inputs))
                    old = Normal(batch.parameters, batch.old_log_std.exp())
                    kl = kl_divergence(old, Normal(new_out, reference.log_std.exp())).sum(-1).mean().item()
                assert 0 < kl < config.kl_target / 1.5
                beta /= 2.0
                expected |= {"kl": kl, "kl_beta": beta}
            else:
                expected["kl"] = measured.approx_kl
                assert math.isnan(row["kl_beta"]), "β means nothing to the clipped objective"
            assert set(row) == ROW_KEYS
            for key, value in expected.items():
                assert row[key] == pytest.approx(value, rel=1e-4, abs=1e-6), (update, key)
            assert (
                row["seconds_env"] == learner.timers["env"] > 0 and row["seconds_inference"] == learner.timers["inference"] > 0
            )
            assert learner.optimizer.param_groups[0]["lr"] == pytest.approx(learning_rate)
    finally:
        learner.close()
    assert learner.position() == f"update 2/{UPDATES}, at step 32 of 48"


def test_rows_before_any_episode_ends_log_nan_returns_without_warnings() -> None:
    # 2 steps: the first episodes end at step 3.
    learner = PPO(tiny_config(n_steps=2, total_steps=4, batch_size=4))
    try:
        rollout = learner.collect_rollout()
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # numpy's "Mean of empty slice" would reach the user's terminal
            row = learner.update(rollout, rollout.env_rewards)
    finally:
        learner.close()
    assert math.isnan(row["return"]) and math.isnan(row["optimised_return"])
    assert learner.progress(row) == {"ret": "nan", "sps": f"{row['steps_per_second']:.0f}"}


def test_progress_shows_the_mean_return_and_the_speed() -> None:
    learner = PPO(tiny_config())
    learner.close()
    assert learner.progress({"return": 12.345, "steps_per_second": 1234.6}) == {"ret": "12.3", "sps": "1235"}


def test_a_diverging_loss_names_the_update_it_happens_in() -> None:
    learner = PPO(tiny_config())
    try:
        learner.step()
        rollout = learner.collect_rollout()
        with torch.no_grad():
            learner.policy.value_head.weight.fill_(float("inf"))  # the critic blown up, as a huge learning rate does
        with pytest.raises(ImitationError, match=r"^PPO update 2/3, epoch 1: the loss is nan"):
            learner.update(rollout, rollout.env_rewards)
    finally:
        learner.close()


def test_a_non_finite_learned_reward_names_its_env_step_and_update() -> None:
    learner = PPO(tiny_config())
    try:
        learner.step()
        rollout = learner.collect_rollout()
        rewards = learned_reward(rollout)
        rewards[2, 1] = float("inf")  # step 2 of env copy 1 in the second rollout: 16 + 2·2 + 1 + 1
        with pytest.raises(
            ImitationError,
            match=r"^TestPPODrift-v0: the learned reward is not finite at env step 22 \(env copy 1\), in PPO update 2/3$",
        ):
            learner.update(rollout, rewards)
    finally:
        learner.close()


def test_a_checkpoint_rebuilds_the_policy_and_resumes_the_clock_and_timers() -> None:
    config = tiny_config()
    original = PPO(config)
    try:
        original.step()
        tensors, state = snapshot(*original.state_dict())
    finally:
        original.close()
    # The checkpoint alone rebuilds the policy (a stopped run's policy can be inspected from it).
    policy = ActorCritic(PolicyConfig.from_json(state["policy"]))
    policy.load_state_dict(unprefixed("policy", tensors))
    features = torch.randn(5, 2)
    assert torch.equal(policy.value(features), original.policy.value(features))

    state |= {"seconds": 100.0, "timers": {"env": 10.0, "inference": 20.0, "update": 30.0}}
    resumed = PPO(config)
    try:
        resumed.load_state_dict((tensors, state))
        rollout = resumed.collect_rollout()
        before, started = resumed.clock.seconds, time.perf_counter()
        row = resumed.update(rollout, rollout.env_rewards)
        elapsed, after = time.perf_counter() - started, resumed.clock.seconds
    finally:
        resumed.close()
    assert row["step"] == 32.0 and row["learning_rate"] == pytest.approx(config.learning_rate * 2 / 3)
    # Seconds and timers go on from the checkpoint's.
    assert 32.0 / after <= row["steps_per_second"] <= 32.0 / before and before > 100.0
    assert 30.0 < row["seconds_update"] <= 30.0 + elapsed
    assert row["seconds_env"] > 10.0 and row["seconds_inference"] > 20.0


def test_a_checkpoint_loads_from_before_the_first_update_up_to_the_last() -> None:
    config = tiny_config()
    learner = PPO(config)
    try:
        tensors, state = snapshot(*learner.state_dict())
        learner.load_state_dict((tensors, state))
        assert learner.updates == 0 and not learner.done
        learner.load_state_dict((tensors, state | {"update": UPDATES}))
        assert learner.done
        with pytest.raises(ImitationError, match=r"^the checkpoint's next update is 4, outside 0\.\.3 for this run"):
            learner.load_state_dict((tensors, state | {"update": UPDATES + 1}))
    finally:
        learner.close()


def test_config_from_json_ignores_unknown_keys() -> None:
    """config.json of a run holds more than PPOConfig's fields (a later version's, or another tool's)."""
    config = PPOConfig.from_json({"env_id": "Pendulum-v1", "n_envs": 2, "hidden_sizes": [16], "not_a_field": 1})
    assert config == PPOConfig(env_id="Pendulum-v1", n_envs=2, hidden_sizes=[16])


@pytest.mark.parametrize(
    ("values", "copies", "message"),
    [
        # Row 2 of a (3, 2, 2) observation batch: env copy 2, the vector env's step 10 + 2 + 1.
        (
            dict(observation=np.where(np.arange(12).reshape(3, 2, 2) == 9, np.nan, 0.0)),
            None,
            "non-finite observation at env step 13 (env copy 2)",
        ),
        (dict(reward=np.array([0.0, -np.inf, 1.0])), None, "non-finite reward at env step 12 (env copy 1)"),
        # Final observations come only for the copies whose episode ended: row 1 is copy 4.
        (
            dict(final_observation=np.array([[0.0, 0.0], [0.0, np.inf]])),
            np.array([1, 4]),
            "non-finite final observation at env step 15 (env copy 4)",
        ),
    ],
)
def test_a_non_finite_step_names_the_env_step_and_copy(values: dict, copies: np.ndarray | None, message: str) -> None:
    with pytest.raises(ImitationError, match=rf"^Env-v0: the environment returned a {re.escape(message)}; PPO needs finite"):
        check_finite_step("Env-v0", 10, copies, **values)


def test_finite_and_integer_steps_pass() -> None:
    check_finite_step("Env-v0", 0, observation=np.zeros((2, 3), np.float32), reward=np.array([1.0, -2.0]))
    check_finite_step("Env-v0", 0, observation=np.array([[3, 4]]))  # integer observations are always finite


def test_explained_variance_of_returns_that_do_not_vary_is_hugely_negative() -> None:
    """1 − Var(R − V) / (Var(R) + 1e-8): with γ = 0 and a constant reward of 1, R = (1 − V) + V is
    exactly 1 (V stays within [0.5, 2]), so a critic whose V varies explains nothing: the row says
    1 − Var(V) / 1e-8, far below 0, not a division by zero."""
    learner = PPO(tiny_config(gamma=0.0))
    try:
        with torch.no_grad():
            learner.policy.value_head.weight.mul_(0.01)
            learner.policy.value_head.bias.fill_(1.0)
        rollout = learner.collect_rollout()
        with torch.no_grad():
            values = learner.policy.value(rollout.observations.reshape(-1, 2))
        assert values.min() >= 0.5 and values.max() <= 2.0
        row = learner.update(rollout, torch.ones(N_STEPS, N_ENVS))
    finally:
        learner.close()
    expected = 1.0 - torch.var(1.0 - values).item() / 1e-8
    assert expected < -10.0 and row["explained_variance"] == pytest.approx(expected, rel=1e-3)


class Chain(gym.Env):
    """Five states in a row (Discrete observations), moved left or right by the action and
    rewarded by the state's number; reaching the right end terminates, the time limit truncates."""

    observation_space = gym.spaces.Discrete(5)
    action_space = gym.spaces.Discrete(2)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.state = int(self.np_random.integers(0, 4))
        return self.state, {}

    def step(self, action):
        self.state = min(max(self.state + 2 * int(action) - 1, 0), 4)
        return self.state, float(self.state), self.state == 4, False, {}


class NonFiniteDrift(Drift):
    """Drift whose env copy 1 (told apart by the seed of its first reset: copy i gets seed + i)
    returns a NaN observation or reward at its step `at`, counting across episodes."""

    def __init__(self, what: str, at: int) -> None:
        super().__init__()
        self.what, self.at, self.copy, self.steps = what, at, None, 0

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        if seed is not None:
            self.copy = seed
        return super().reset(seed=seed, options=options)

    def step(self, action):
        observation, reward, terminated, truncated, info = super().step(action)
        self.steps += 1
        if self.copy == 1 and self.steps == self.at:
            if self.what == "reward":
                reward = float("nan")
            else:
                observation[1] = np.nan
        return observation, reward, terminated, truncated, info


gym.register("TestPPOChain-v0", entry_point=Chain, max_episode_steps=4)
for name, what, at in [("Observation", "observation", 11), ("Reward", "reward", 11), ("FinalObservation", "observation", 10)]:
    gym.register(f"TestPPONaN{name}-v0", entry_point=NonFiniteDrift, kwargs=dict(what=what, at=at), max_episode_steps=4)


@pytest.mark.parametrize("env_id", ["TestPPODrift-v0", "TestPPODriftDiscrete-v0", "TestPPOChain-v0"])
def test_a_rollout_is_what_hand_stepped_copies_of_the_envs_see(env_id: str) -> None:
    """Every field of the rollout against copies of the envs stepped by hand with the rollout's
    env actions (copy i reset with seed i, then reset unseeded where an episode ends): states in
    the envs' own dtype (integers for Discrete observations), the true final state where an
    episode ended, rewards, terminated/truncated, log π_k(a|s), and the episodes' returns."""
    config = tiny_config(env_id=env_id)
    learner = PPO(config)
    try:
        rollout = learner.collect_rollout()
    finally:
        learner.close()
    policy = learner.policy
    discrete_observations = env_id == "TestPPOChain-v0"
    dtype = torch.int64 if discrete_observations else torch.float32
    assert rollout.observations.dtype == rollout.next_observations.dtype == dtype
    assert rollout.terminated.any() and rollout.truncated.any()

    envs = [gym.make(env_id) for _ in range(N_ENVS)]
    observations = [env.reset(seed=i)[0] for i, env in enumerate(envs)]
    returns, finished = np.zeros(N_ENVS), []
    for t in range(N_STEPS):
        assert torch.equal(rollout.observations[t], torch.as_tensor(np.array(observations)).to(dtype)), t
        with torch.no_grad():
            distribution = policy.distribution(policy.encode(rollout.observations[t]))
            log_probs = policy.log_prob(distribution, rollout.actions[t])
        assert torch.allclose(rollout.log_probs[t], log_probs, atol=1e-5), t
        env_actions = policy.to_env_action(rollout.actions[t])
        assert torch.equal(rollout.env_actions[t], torch.as_tensor(env_actions).float().reshape(rollout.env_actions[t].shape))
        for i, env in enumerate(envs):
            observation, reward, terminated, truncated, _ = env.step(env_actions[i])
            assert torch.equal(rollout.next_observations[t, i], torch.as_tensor(observation).to(dtype)), (t, i)
            assert rollout.env_rewards[t, i].item() == pytest.approx(reward, rel=1e-6)
            assert (rollout.terminated[t, i].item(), rollout.truncated[t, i].item()) == (terminated, truncated), (t, i)
            returns[i] += reward
            if terminated or truncated:
                finished.append(returns[i])
                returns[i] = 0.0
                observation, _ = env.reset()
            observations[i] = observation
    assert list(learner.recent_returns) == pytest.approx(finished, rel=1e-6)


@pytest.mark.parametrize(
    ("name", "message"),
    [
        # Copy 1's 11th step is the first of its 4th episode (3 + 4 + 3 steps before): vector step 10,
        # the third of the second rollout, env step 16 + 2·2 + 1 + 1.
        ("Observation", "observation at env step 22 (env copy 1)"),
        ("Reward", "reward at env step 22 (env copy 1)"),
        # Its 10th step ends its 3rd episode: the NaN is in the final state, not in the reset one.
        ("FinalObservation", "final observation at env step 20 (env copy 1)"),
    ],
)
def test_a_non_finite_env_output_stops_the_rollout_naming_its_env_step(name: str, message: str) -> None:
    env_id = f"TestPPONaN{name}-v0"
    learner = PPO(tiny_config(env_id=env_id))
    try:
        learner.collect_rollout()
        with pytest.raises(
            ImitationError, match=rf"^{env_id}: the environment returned a non-finite {re.escape(message)}; PPO needs finite"
        ):
            learner.collect_rollout()
    finally:
        learner.close()


def test_the_running_observation_statistics_are_those_of_every_state_the_rollout_saw() -> None:
    learner = PPO(tiny_config(normalize_observations=True))
    try:
        rollout = learner.collect_rollout()
    finally:
        learner.close()
    seen = rollout.observations.reshape(-1, 2).double()
    statistics = learner.policy.obs_rms
    assert statistics is not None
    # The statistics start from a prior of weight 1e-4: a relative error of about 1e-5 over 16 states.
    assert torch.allclose(statistics.mean, seen.mean(0), rtol=1e-4, atol=1e-6)
    assert torch.allclose(statistics.var, seen.var(0, unbiased=False), rtol=1e-4, atol=1e-6)


def test_the_logged_returns_are_the_means_of_the_last_20_episodes() -> None:
    """64 steps of 2 envs end about 36 episodes: the row's returns (the env's, and the one
    optimised) are the means of the last 20, and the checkpoint keeps those 20."""
    learner = PPO(tiny_config(n_steps=64, total_steps=128, batch_size=128, n_epochs=1))
    try:
        rollout = learner.collect_rollout()
        rewards = 2.0 * rollout.env_rewards + 1.0
        row = learner.update(rollout, rewards)
        _, state = learner.state_dict()
    finally:
        learner.close()
    true_returns = episode_returns(rollout.env_rewards, rollout, np.zeros(N_ENVS))
    optimised_returns = episode_returns(rewards, rollout, np.zeros(N_ENVS))
    assert len(true_returns) > 30
    assert state["recent_returns"] == pytest.approx(true_returns[-20:], rel=1e-5)
    assert state["recent_optimised_returns"] == pytest.approx(optimised_returns[-20:], rel=1e-5)
    assert row["return"] == pytest.approx(np.mean(true_returns[-20:]), rel=1e-5)
    assert row["optimised_return"] == pytest.approx(np.mean(optimised_returns[-20:]), rel=1e-5)


def test_the_timers_add_up_to_the_time_spent_in_rollouts_and_updates() -> None:
    """Environment and inference time together cover a rollout's loop (all but the first
    rollout's reset) and no more; update time is the update's. Fresh learners start from zero."""
    learner = PPO(tiny_config())
    try:
        started = time.perf_counter()
        learner.collect_rollout()  # resets the envs first, outside both timers
        first = time.perf_counter() - started
        assert learner.timers["env"] > 0 and learner.timers["inference"] > 0
        assert learner.timers["env"] + learner.timers["inference"] <= first
        before = dict(learner.timers)
        started = time.perf_counter()
        rollout = learner.collect_rollout()
        second = time.perf_counter() - started
        env, inference = (learner.timers[key] - before[key] for key in ("env", "inference"))
        assert env > 0 and inference > 0 and 0.9 * second <= env + inference <= second
        assert learner.timers["update"] == 0.0
        started = time.perf_counter()
        learner.update(rollout, rollout.env_rewards)
        assert 0 < learner.timers["update"] <= time.perf_counter() - started
    finally:
        learner.close()


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"objective": "trpo"}, "objective must be one of clip, kl, got 'trpo'"),
        ({"n_epochs": 0}, "n_epochs must be at least 1, got 0"),
        ({"total_steps": 7, "n_envs": 2, "n_steps": 4}, "total_steps 7 is less than one rollout (2 envs × 4 steps)"),
        ({"learning_rate": 0.0}, "learning_rate must be a positive number below 1e30, got 0.0"),
        ({"learning_rate": 1e30}, "learning_rate must be a positive number below 1e30, got 1e+30"),
        ({"learning_rate": float("nan")}, "learning_rate must be a positive number below 1e30, got nan"),
    ],
)
def test_a_config_out_of_range_is_refused_naming_the_field(changes: dict, message: str) -> None:
    with pytest.raises(ConfigError, match=f"^{re.escape(message)}$") as raised:
        PPOConfig(env_id="CartPole-v1", **changes).validate()
    assert raised.value.owner == "PPOConfig"


def test_a_config_at_the_edges_of_its_ranges_is_accepted() -> None:
    PPOConfig(
        env_id="CartPole-v1", total_steps=8, n_envs=2, n_steps=4, batch_size=1, n_epochs=1, learning_rate=1e29
    ).validate()
    PPOConfig(env_id="CartPole-v1", learning_rate=1e-30).validate()


def test_the_learner_is_built_as_configured() -> None:
    """The policy's architecture, the device, Adam's ε, and the seed of numpy's global generator
    (for whatever draws from it next, a reward learner's sampling say)."""
    options = dict(hidden_sizes=[5, 3], activation="relu", shared_trunk=True, normalize_observations=True, log_std_init=-0.7)
    learner = PPO(tiny_config(seed=7, **options))
    learner.close()
    drawn = np.random.random()
    np.random.seed(7)
    assert drawn == np.random.random()
    for name, value in options.items():
        assert getattr(learner.policy.config, name) == value, name
    assert torch.equal(learner.policy.log_std.detach(), torch.full((2,), -0.7))
    assert learner.device == torch.device("cpu")
    assert learner.optimizer.defaults["eps"] == 1e-5  # CleanRL's Adam ε


def test_an_unknown_device_is_refused_naming_the_setting() -> None:
    with pytest.raises(ConfigError, match=r"^device 'abacus': ") as raised:
        PPO(tiny_config(device="abacus"))
    assert raised.value.field == "device"


def test_envs_step_in_this_process_unless_async_envs_asks_for_spawned_workers() -> None:
    """Forking a process whose torch threads have run can deadlock: async workers are spawned."""
    envs = make_vector_env("TestPPODrift-v0", 2)
    envs.close()
    assert isinstance(envs, gym.vector.SyncVectorEnv)
    learner = PPO(tiny_config(env_id="Pendulum-v1", async_envs=True, total_steps=16, n_steps=8))
    try:
        assert isinstance(learner.envs, gym.vector.AsyncVectorEnv) and learner.envs.num_envs == N_ENVS
        assert all(isinstance(process, multiprocessing.context.SpawnProcess) for process in learner.envs.processes)
    finally:
        learner.close()
