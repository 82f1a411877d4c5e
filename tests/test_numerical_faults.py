"""NaN and ±inf are stopped where they enter, with the step or episode named, through the CLI:
an environment that returns NaN while recording or during PPO rollouts, demo files holding NaN
loaded by every learner, and losses that diverge."""

from __future__ import annotations

import dataclasses
import subprocess
from pathlib import Path

import numpy as np
import pytest
import torch
from support import DATASETS, run_cli_many
from test_cli import assert_one_line_error

from imitation.data.mcap.reader import DemoFile
from imitation.data.mcap.writer import write_episodes
from imitation.errors import ImitationError
from imitation.runs import has_checkpoint


def assert_nothing_written(*paths: Path) -> None:
    for path in paths:
        for leftover in (path, path.with_name(path.name + ".partial")):
            assert not leftover.exists(), f"{leftover} was left behind"


def assert_checkpoint_kept(result: subprocess.CompletedProcess, run: Path) -> None:
    """A failure after a checkpoint of work done keeps it, and says so (nothing lost)."""
    partial = run.with_name(run.name + ".partial")
    assert not run.exists() and has_checkpoint(partial), f"{partial} holds no checkpoint"
    assert f"{partial} keeps the run's last checkpoint" in result.stderr, result.stderr


def copy_with_nan(source: Path, out: Path, *, episode: int, step: int, field: str) -> Path:
    """A copy of a bundled demo file with one NaN, written as another tool might (no checks)."""
    demo = DemoFile(source)
    episodes = demo.read_episodes()
    array = np.array(getattr(episodes[episode], field))  # a writable copy
    array[step] = np.nan
    episodes[episode] = dataclasses.replace(episodes[episode], **{field: array})
    return write_episodes(out, episodes, env_id=demo.env_id, observation_space=demo.observation_space, action_space=demo.action_space, finite_only=False)


def test_nan_from_an_environment_is_named_by_episode_and_step(tmp_path: Path) -> None:
    record = ["record", "--expert", "random", "--episodes", "10", "--seed", "0", "--quiet"]
    cases = {
        "record obs": [*record, "--env", "nan_envs:NaNObservation-v0", "--out", tmp_path / "obs.mcap"],
        "record reward": [*record, "--env", "nan_envs:NaNReward-v0", "--out", tmp_path / "reward.mcap"],
        "ppo obs": ["train", "ppo", "--env", "nan_envs:NaNObservation-v0", "--steps", "4096", "--quiet", "--out", tmp_path / "ppo-obs"],
        "ppo reward": ["train", "ppo", "--env", "nan_envs:NaNReward-v0", "--steps", "4096", "--quiet", "--out", tmp_path / "ppo-reward"],
        "ppo final obs": ["train", "ppo", "--env", "nan_envs:NaNFinalObservation-v0", "--steps", "4096", "--quiet", "--out", tmp_path / "ppo-final"],
    }
    results = dict(zip(cases, run_cli_many(list(cases.values()))))
    # Each env copy returns NaN on its 290th step() call: episode 5, step 40 (episodes last 50).
    assert_one_line_error(results["record obs"], f"{tmp_path / 'obs.mcap'}: episode 5, step 40: the observation is nan")
    assert_one_line_error(results["record reward"], f"{tmp_path / 'reward.mcap'}: episode 5, step 39: the reward is nan")
    # PPO's 4 copies step together: 289 vector steps (1156 env steps) before, copy 0 is step 1157.
    assert_one_line_error(results["ppo obs"], "nan_envs:NaNObservation-v0: the environment returned a non-finite observation at env step 1157 (env copy 0)")
    assert_one_line_error(results["ppo reward"], "the environment returned a non-finite reward at env step 1157 (env copy 0)")
    # On call 300 the episode ends: the NaN is in the final observation, which the env has replaced by a reset one.
    assert_one_line_error(results["ppo final obs"], "the environment returned a non-finite final observation at env step 1197 (env copy 0)")
    # The NaN comes after the checkpoint at a tenth of the run (410 steps): kept, to resume once the env is mended.
    for case, run in (("ppo obs", "ppo-obs"), ("ppo reward", "ppo-reward"), ("ppo final obs", "ppo-final")):
        assert_checkpoint_kept(results[case], tmp_path / run)
    # The recordings' five finished episodes are kept, for `imitation recover`, and said so.
    for name in ("obs.mcap", "reward.mcap"):
        assert f"{tmp_path / name}.partial keeps 5 finished episode(s)" in results[f"record {name.split('.')[0]}"].stderr
        assert not (tmp_path / name).exists() and len(DemoFile(tmp_path / f"{name}.partial", salvage=True)) == 5


def test_every_learner_refuses_demos_holding_nan_naming_file_episode_and_step(tmp_path: Path) -> None:
    cartpole = copy_with_nan(DATASETS / "CartPole-v1.mcap", tmp_path / "cartpole-nan.mcap", episode=3, step=10, field="observations")
    grid = copy_with_nan(DATASETS / "GridWorld8x8-v0.mcap", tmp_path / "grid-nan.mcap", episode=7, step=2, field="rewards")
    good = DATASETS / "CartPole-v1.mcap"
    runs = {name: tmp_path / name for name in ("bc", "dagger", "gcl", "mce")}
    cases = {
        # The bad file second: the episode is named within its own file.
        "bc": ["train", "bc", "--demos", good, cartpole, "--env", "CartPole-v1", "--epochs", "1", "--quiet", "--out", runs["bc"]],
        "dagger": ["train", "dagger", "--demos", cartpole, "--env", "CartPole-v1", "--expert", "scripted", "--rounds", "1", "--quiet", "--out", runs["dagger"]],
        "gcl": ["train", "irl", "--method", "gcl", "--demos", cartpole, "--env", "CartPole-v1", "--steps", "2048", "--quiet", "--out", runs["gcl"]],
        "mce": ["train", "irl", "--method", "mce", "--demos", grid, "--env", "imitation/GridWorld8x8-v0", "--iterations", "2", "--quiet", "--out", runs["mce"]],
    }
    results = dict(zip(cases, run_cli_many(list(cases.values()))))
    for name in ("bc", "dagger", "gcl"):
        assert_one_line_error(results[name], f"{cartpole}: episode 3, step 10: the observation is nan; learners need finite")
    assert_one_line_error(results["mce"], f"{grid}: episode 7, step 2: the reward is nan; learners need finite")
    assert_nothing_written(*runs.values())


# ------------------------------------------------------------------------------------------------
# Diverging losses: each trainer stops at the first non-finite loss and names where it happened.


def test_bc_names_the_epoch_of_a_nan_loss(tmp_path: Path) -> None:
    result = run_cli_many([["train", "bc", "--demos", DATASETS / "Pendulum-v1.mcap", "--env", "Pendulum-v1", "--lr", "1000", "--epochs", "5", "--quiet", "--out", tmp_path / "run"]])[0]
    assert_one_line_error(result, "BC epoch ", "the loss is", "diverged; try a lower learning rate")
    assert_nothing_written(tmp_path / "run")


def test_ppo_names_the_update_and_epoch_of_a_nan_loss() -> None:
    from imitation.algorithms.ppo import PPO, PPOConfig
    from imitation.jobs.loop import run

    config = PPOConfig(env_id="CartPole-v1", total_steps=2048, n_envs=2, n_steps=64, learning_rate=1e20, anneal_lr=False, max_grad_norm=1e20)
    learner = PPO(config)
    try:
        with pytest.raises(ImitationError, match=r"^PPO update \d+/16, epoch \d+: the loss is (nan|inf|-inf) \(diverged"):
            run(learner)
    finally:
        learner.close()


def test_gcl_names_the_update_and_step_of_a_nan_reward_loss() -> None:
    from imitation.algorithms.gcl import GCLConfig, GuidedCostLearning
    from imitation.algorithms.ppo import PPO, PPOConfig
    from imitation.data.loader import load_transitions, transitions_to_torch
    from imitation.envs.make import make_env
    from imitation.jobs.loop import run
    from imitation.rewards import make_reward_model

    env = make_env("CartPole-v1")
    reward = make_reward_model(env.observation_space, env.action_space, hidden_sizes=[16])
    demos = transitions_to_torch(load_transitions(DATASETS / "CartPole-v1.mcap"))
    ppo = PPO(PPOConfig(env_id="CartPole-v1", total_steps=512, n_envs=2, n_steps=64))  # 4 updates
    learner = GuidedCostLearning(ppo, reward, demos, GCLConfig(learning_rate=1e20, warmup_steps=5, gradient_penalty=0.0))
    try:
        with pytest.raises(ImitationError, match=r"^GCL reward update 1, step \d+/13: the loss is (nan|inf|-inf) \(diverged; try a lower learning rate\)"):
            run(learner)
    finally:
        ppo.close()


@pytest.mark.parametrize("method", ["gail", "airl"])
def test_an_adversarial_discriminator_names_the_round_and_step_of_a_nan_loss(method: str) -> None:
    from imitation.algorithms.adversarial import AdversarialConfig, AdversarialImitation
    from imitation.algorithms.airl import AIRLDiscriminator
    from imitation.algorithms.gail import GAILDiscriminator
    from imitation.algorithms.ppo import PPO, PPOConfig
    from imitation.data.loader import load_transitions, transitions_to_torch
    from imitation.envs.make import make_env
    from imitation.jobs.loop import run
    from imitation.rewards import make_reward_model

    env = make_env("CartPole-v1")

    def net(inputs: str, output: str = "linear"):
        return make_reward_model(env.observation_space, env.action_space, hidden_sizes=[16], inputs=inputs, output=output)

    discriminator = GAILDiscriminator(net("sa", "softplus")) if method == "gail" else AIRLDiscriminator(net("s"), net("s"), gamma=0.99)
    demos = transitions_to_torch(load_transitions(DATASETS / "CartPole-v1.mcap", next_observations=True))
    ppo = PPO(PPOConfig(env_id="CartPole-v1", total_steps=512, n_envs=2, n_steps=64))  # 4 updates
    learner = AdversarialImitation(ppo, discriminator, demos, AdversarialConfig(method=method, learning_rate=1e20, discriminator_steps=20))
    try:
        with pytest.raises(ImitationError, match=rf"^{method.upper()} discriminator round \d, step \d+/20: the loss is (nan|inf|-inf) \(diverged; try a lower learning rate\)"):
            run(learner)
    finally:
        ppo.close()


def test_maxent_irl_names_the_iteration_of_a_non_finite_reward() -> None:
    from imitation.algorithms.maxent_irl import MaxEntIRL, MaxEntIRLConfig, demo_visitation
    from imitation.envs.make import make_env
    from imitation.envs.tabular import tabular_mdp_of
    from imitation.jobs.loop import run
    from imitation.rewards import make_reward_model

    env = make_env("imitation/GridWorld8x8-v0")
    mdp = tabular_mdp_of(env, where="test")
    target = demo_visitation(DemoFile(DATASETS / "GridWorld8x8-v0.mcap").read_episodes(), n_states=mdp.n_states, horizon=mdp.horizon, discount=1.0)
    model = make_reward_model(env.observation_space, env.action_space, feature_table=mdp.features, hidden_sizes=[])
    with torch.no_grad():
        next(model.parameters()).fill_(float("nan"))  # what a diverged step leaves behind
    with pytest.raises(ImitationError, match=r"^mce IRL iteration 1: the learned reward is not finite \(diverged; try a lower learning rate\)"):
        run(MaxEntIRL(mdp, target, model, MaxEntIRLConfig(iterations=5)))
