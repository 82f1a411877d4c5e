"""The PPO learner around `ppo_update`: each update is GAE over the rollout followed by
`ppo_update` on the flattened rollout (checked against a reference written from the notes), its
logged row is the hand computation of every field, learned rewards are kept as the notes say, and
its checkpoint round trips. Tiny rollouts (2 envs × 8 steps of a 2-D point) keep each test fast."""

from __future__ import annotations

import copy
import math
import re
import time
import warnings

import gymnasium as gym
import numpy as np
import pytest
import torch
from torch.distributions import Normal, kl_divergence

from imitation.algorithms.ppo import PPO, PPOConfig, RewardScaler, UpdateBatch, check_finite_step, compute_gae, ppo_update
from imitation.checkpoints import snapshot, unprefixed
from imitation.envs.rollout import Rollout
from imitation.errors import ImitationError
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
        features=features,
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
                    new_out = reference.action_head(reference.actor_trunk(batch.features))
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
