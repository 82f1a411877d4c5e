"""Training jobs: an algorithm, its run directory, plots and a final evaluation, as one call.

The CLI calls these; learners in imitation.algorithms know nothing of run directories.
"""

from __future__ import annotations

import os
from contextlib import closing, contextmanager, nullcontext
from typing import Any, Iterator

import gymnasium as gym
import numpy as np
import torch
from tqdm import tqdm

from imitation import __version__
from imitation.algorithms.bc import BCConfig, policy_options, train_bc
from imitation.algorithms.dagger import DAggerConfig, train_dagger
from imitation.algorithms.gcl import GCLConfig, GuidedCostLearning
from imitation.algorithms.maxent_irl import (
    MaxEntIRLConfig, Dynamics, all_state_rewards, demo_visitation, expected_return, train_maxent_irl,
)
from imitation.algorithms.ppo import PPOConfig, Rollout, train_ppo
from imitation.checkpoints import Checkpointing, TrainingInterrupted, prefixed
from imitation.data.loader import TransitionTensors, check_episodes_finite, load_transitions, split_episode_tails, split_episodes, transitions_to_torch
from imitation.data.spaces import check_spaces_fit
from imitation.data.store import DemoDataset
from imitation.envs.make import make_env
from imitation.envs.tabular import TabularMDP, tabular_mdp_of
from imitation.errors import ImitationError
from imitation.evaluation.plots import plot_grid_maps
from imitation.evaluation.policy import evaluate_policy
from imitation.experts.load import load_expert, make_env_for_expert
from imitation.experts.tabular import soft_optimal_policy
from imitation.policies import ActorCritic, SingleObservationPolicy, make_policy, policy_tensors
from imitation.rewards import load_reward, make_reward_model, relabel_rollout, reward_tensors
from imitation.runs import RunWriter, plot_curve
from imitation.seeding import seed_everything

# What may differ between an interrupted run and its --resume: where and how fast it runs.
RESUME_IGNORE = ("creator", "ppo.device", "ppo.threads", "ppo.async_envs", "bc.device", "bc.threads", "dagger.bc.device", "dagger.bc.threads")
EVAL_SEED = 10_000  # evaluation episodes start here, away from training and demo seeds
EVAL_EPISODES = 10


def _final_evaluation(policy: ActorCritic, env: gym.Env) -> dict[str, Any]:
    """The deterministic evaluation every run records in metrics.json (returns list left out)."""
    evaluation = evaluate_policy(SingleObservationPolicy(policy), env, episodes=EVAL_EPISODES, seed=EVAL_SEED)
    return {key: value for key, value in evaluation.items() if key != "returns"}


@contextmanager
def _resumable(run: RunWriter) -> Iterator[None]:
    """Ctrl-C stopped the trainer with a checkpoint saved: say where, and how to continue."""
    try:
        yield
    except TrainingInterrupted as stopped:
        raise TrainingInterrupted(f"{stopped}; its checkpoint is in {run.partial}: run the same command with --resume to continue") from None


def _fingerprints(dataset: DemoDataset | None) -> list[str]:
    """What the run records of its demo files' content, so that --resume can tell a change."""
    return [file.fingerprint for file in dataset.files] if dataset is not None else []


def _check_demos_fit_env(dataset: DemoDataset, env: gym.Env) -> None:
    first = dataset.files[0].path
    if dataset.num_transitions == 0:
        raise ImitationError(f"{first}: the demos hold no transitions (no episode, or only empty ones)")
    check_spaces_fit("demos'", dataset.observation_space, dataset.action_space, env, where=str(first))


def bc_job(
    demos: list[str], env_id: str | None, config: BCConfig, out: str | os.PathLike, *, progress: bool = True, resume: bool = False
) -> dict[str, Any]:
    """Behavioural cloning on `demos` into run directory `out`.

    Without `env_id` it trains offline (recordings with no simulator behind them): the policy
    takes the demos' own spaces and the run reports the validation loss only, no returns.
    `resume` continues the interrupted run in `out`.partial from its checkpoint."""
    seed_everything(config.seed)
    dataset = DemoDataset(demos)
    env = make_env(env_id) if env_id else None
    if env is not None:
        _check_demos_fit_env(dataset, env)
    elif dataset.num_transitions == 0:
        raise ImitationError(f"{dataset.files[0].path}: the demos hold no transitions (no episode, or only empty ones)")
    spaces = env if env is not None else dataset
    try:
        policy = make_policy(spaces.observation_space, spaces.action_space, **policy_options(config))
    except ImitationError as error:
        raise ImitationError(f"{f'--env {env_id}' if env is not None else dataset.files[0].path}: {error}") from None
    config.validate(policy.is_continuous)
    train, validation, split = _bc_split(dataset, config, offline=env is None)

    def env_return(candidate: ActorCritic) -> float:
        return evaluate_policy(SingleObservationPolicy(candidate), env, episodes=5, seed=EVAL_SEED)["mean_return"]

    with closing(env) if env is not None else nullcontext(), RunWriter(out, config={
        "kind": "bc", "env_id": env_id, "offline": env is None, "demos_env_id": dataset.env_id, "creator": f"imitation-mcap {__version__}",
        "demos": [str(p) for p in demos], "demo_fingerprints": _fingerprints(dataset), "bc": vars(config).copy(), "policy": policy.config.to_json(), "split": split,
    }, x_axis="epoch", resume=resume, resume_ignore=RESUME_IGNORE) as run, _resumable(run):
        checkpoints = Checkpointing(save=run.save_checkpoint, resume=run.resumed)
        result = train_bc(
            policy, train, validation, config, evaluate=env_return if env is not None else None, log=run.log, progress=progress, checkpoints=checkpoints
        )
        run.save_weights(policy_tensors(result.policy.cpu()))
        title = f"BC on {env_id or dataset.env_id or 'offline demos'}"
        plot_curve(run.file("loss_curve.png"), run.history, x="epoch", ys=["train_loss", "validation_loss"], title=f"{title}: loss")
        if env is not None:
            plot_curve(run.file("return_curve.png"), run.history, x="epoch", ys=["return"], title=f"{title}: return")
        metrics = {
            "env_id": env_id,
            "offline": env is None,
            "train_transitions": len(train),
            "validation_transitions": len(validation) if validation is not None else 0,
            "epochs": len(result.history),
            "best_epoch": result.best_epoch,
            "best_validation_loss": min((row["validation_loss"] for row in result.history), default=None),
            "seconds": result.seconds,
            "samples_per_second": result.history[-1]["samples_per_second"],
            "eval": _final_evaluation(result.policy.cpu(), env) if env is not None else None,
        }
        run.finish(metrics)
    return {"run": str(run.path), **metrics}


def _bc_split(dataset: DemoDataset, config: BCConfig, *, offline: bool) -> tuple[TransitionTensors, TransitionTensors | None, dict[str, Any]]:
    """Training and validation transitions: whole episodes held out; offline, where the
    validation loss is all a run reports, each episode's last steps when there are too few
    episodes to spare one (a single long recording)."""
    train_ids, validation_ids = split_episodes(len(dataset), validation_fraction=config.validation_fraction, seed=config.seed)
    if validation_ids or not offline or config.validation_fraction == 0:
        train = transitions_to_torch(load_transitions(dataset, episodes=train_ids, next_observations=False))
        validation = transitions_to_torch(load_transitions(dataset, episodes=validation_ids, next_observations=False)) if validation_ids else None
        return train, validation, {"train_episodes": train_ids, "validation_episodes": validation_ids}
    every = load_transitions(dataset, next_observations=False)
    train_rows, validation_rows = split_episode_tails(every, validation_fraction=config.validation_fraction)
    tensors = transitions_to_torch(every)
    validation = tensors.select(torch.from_numpy(validation_rows)) if len(validation_rows) else None
    return tensors.select(torch.from_numpy(train_rows)), validation, {
        "episode_tails": config.validation_fraction, "train_transitions": len(train_rows), "validation_transitions": len(validation_rows),
    }


def dagger_job(
    env_id: str, expert_spec: str, config: DAggerConfig, out: str | os.PathLike, *, demos: list[str] = (), progress: bool = True,
    resume: bool = False,
) -> dict[str, Any]:
    """DAgger with `expert_spec` into run directory `out`; each round's labelled rollouts are
    written to `out/rounds/round-NN.mcap`. `resume` continues the interrupted run in
    `out`.partial from its checkpoint, with the rounds it had finished."""
    seed_everything(config.seed)
    env = make_env_for_expert(env_id, expert_spec)
    expert = load_expert(expert_spec, env, seed=config.seed)
    given = DemoDataset(demos) if demos else None
    if given is not None:
        _check_demos_fit_env(given, env)
    policy = make_policy(env.observation_space, env.action_space, **policy_options(config.bc))
    config.bc.validate(policy.is_continuous)

    def env_return(candidate: ActorCritic) -> float:
        return evaluate_policy(SingleObservationPolicy(candidate), env, episodes=5, seed=EVAL_SEED)["mean_return"]

    with closing(env), RunWriter(out, config={
        "kind": "dagger", "env_id": env_id, "creator": f"imitation-mcap {__version__}", "expert": expert_spec,
        "demos": [str(p) for p in demos], "demo_fingerprints": _fingerprints(given), "dagger": {**vars(config), "bc": vars(config.bc).copy()},
        "policy": policy.config.to_json(),
    }, x_axis="round", resume=resume, resume_ignore=RESUME_IGNORE) as run, _resumable(run):
        bar = tqdm(total=config.rounds, initial=len(run.history), desc="dagger", unit="round", disable=None if progress else True, dynamic_ncols=True)

        def log(row: dict[str, float]) -> None:
            run.log(row)
            bar.update()
            bar.set_postfix(beta=f"{row['beta']:.2f}", labels=int(row["expert_labels"]), ret=f"{row['return']:.1f}")

        with bar:
            result = train_dagger(
                env, expert, policy, config, round_dir=run.file("rounds"), env_id=env_id, demos=demos, evaluate=env_return, log=log,
                checkpoints=Checkpointing(save=run.save_checkpoint, resume=run.resumed),
            )
        run.save_weights(policy_tensors(result.policy.cpu()))
        plot_curve(run.file("return_curve.png"), run.history, x="expert_labels", ys=["return", "rollout_return"], title=f"DAgger on {env_id}")
        plot_curve(run.file("loss_curve.png"), run.history, x="round", ys=["validation_loss"], title=f"DAgger on {env_id}: validation loss")
        metrics = {
            "env_id": env_id,
            "expert": expert_spec,
            "rounds": len(result.history),
            "expert_labels": int(result.history[-1]["expert_labels"]),
            "round_returns": [row["return"] for row in result.history],
            "eval": _final_evaluation(result.policy.cpu(), env),
        }
        run.finish(metrics)
    return {"run": str(run.path), "round_files": [str(run.path / "rounds" / p.name) for p in result.round_files], **metrics}


def ppo_job(config: PPOConfig, out: str | os.PathLike, *, progress: bool = True, resume: bool = False) -> dict[str, Any]:
    """Train PPO into run directory `out`; returns the metrics also written to metrics.json.
    `resume` continues the interrupted run in `out`.partial from its checkpoint."""
    config.validate()
    seed_everything(config.seed)
    rollout_rewards = None
    if config.reward_run is not None:
        reward_model = load_reward(config.reward_run)
        with closing(make_env(config.env_id)) as env:  # fail before training, with one line
            check_spaces_fit("reward model's", reward_model.observation_space, reward_model.action_space, env, where=f"--reward {config.reward_run}")

        def rollout_rewards(rollout: Rollout, policy: ActorCritic) -> torch.Tensor:
            return relabel_rollout(reward_model, rollout)

    with RunWriter(
        out, config={"kind": "ppo", "env_id": config.env_id, "creator": f"imitation-mcap {__version__}", "ppo": vars(config).copy()},
        resume=resume, resume_ignore=RESUME_IGNORE,
    ) as run, _resumable(run):
        checkpoints = Checkpointing(save=run.save_checkpoint, resume=run.resumed)
        result = train_ppo(config, rollout_rewards=rollout_rewards, log=run.log, progress=progress, checkpoints=checkpoints)
        tensors = policy_tensors(result.policy)
        if result.reward_scaler is not None:
            tensors |= prefixed("reward_scaler", result.reward_scaler.stats.state_dict())
        run.save_weights(tensors)
        run.update_config(policy=result.policy.config.to_json())
        ys = ["return"] + (["optimised_return"] if config.reward_run else [])
        plot_curve(run.file("learning_curve.png"), run.history, x="step", ys=ys, title=f"PPO ({config.objective}) on {config.env_id}")
        env = make_env(config.env_id)
        metrics = {
            "env_id": config.env_id,
            "objective": config.objective,
            "steps": result.steps,
            "seconds": result.seconds,
            "steps_per_second": result.steps / result.seconds,
            "final_train_return": result.history[-1]["return"] if result.history else None,
            "eval": _final_evaluation(result.policy.cpu(), env),
        }
        env.close()
        run.finish(metrics)
    return {"run": str(run.path), **metrics}


def tabular_irl_job(
    demos: list[str], env_id: str, config: MaxEntIRLConfig, out: str | os.PathLike, *, progress: bool = True, resume: bool = False
) -> dict[str, Any]:
    """Tabular MaxEnt or MCE IRL on `demos` of a tabular env into run directory `out`; `resume`
    continues the interrupted run in `out`.partial from its checkpoint.

    The reward is judged by the true return of the policy that is soft-optimal for it, computed
    exactly from the known dynamics and normalised between the uniform random policy (0) and
    the soft-optimal policy for the true reward (1)."""
    config.validate()
    seed_everything(config.seed)
    with closing(make_env(env_id)) as env:
        mdp = tabular_mdp_of(env, where=f"--method {config.method}")
        dataset = DemoDataset(demos)
        _check_demos_fit_env(dataset, env)
        observation_space, action_space = env.observation_space, env.action_space
    demo_episodes = dataset.read_episodes()
    check_episodes_finite(demo_episodes, dataset)
    occupancy_target = demo_visitation(demo_episodes, n_states=mdp.n_states, horizon=mdp.horizon, discount=config.discount)
    model = make_reward_model(observation_space, action_space, feature_table=mdp.features, hidden_sizes=list(config.hidden_sizes))

    with RunWriter(out, config={
        "kind": "reward", "env_id": env_id, "creator": f"imitation-mcap {__version__}", "demos": [str(p) for p in demos],
        "demo_fingerprints": _fingerprints(dataset), "irl": vars(config).copy(), "reward": model.config.to_json(),
    }, x_axis="iteration", resume=resume, resume_ignore=RESUME_IGNORE) as run, _resumable(run):
        bar = tqdm(
            total=config.iterations, initial=len(run.history), desc=f"irl {config.method}", unit="it", disable=None if progress else True, dynamic_ncols=True,
        )

        def log(row: dict[str, float]) -> None:
            run.log(row)
            bar.update()
            bar.set_postfix(error=f"{row['occupancy_error']:.2e}", loss=f"{row['loss']:.3f}")

        with bar:
            result = train_maxent_irl(mdp, occupancy_target, model, config, log=log, checkpoints=Checkpointing(save=run.save_checkpoint, resume=run.resumed))
        run.save_weights(reward_tensors(model))
        learned_reward = all_state_rewards(model, mdp.n_states).detach().double().numpy()
        returns = tabular_policy_returns(mdp, learned_reward, discount=config.discount)
        plot_curve(run.file("irl_curve.png"), run.history, x="iteration", ys=["loss", "occupancy_error"], title=f"{config.method} IRL on {env_id}")
        if mdp.grid_shape is not None:
            plot_grid_maps(run.file("reward_maps.png"), {"true reward": mdp.reward, "learned reward": learned_reward}, grid_shape=mdp.grid_shape, title=env_id)
            plot_grid_maps(run.file("occupancy_maps.png"), {"demos' visitation": occupancy_target, "learned visitation": result.occupancy}, grid_shape=mdp.grid_shape, title=env_id)
        last = result.history[-1]
        metrics = {
            "env_id": env_id,
            "method": config.method,
            "demo_episodes": len(dataset),
            "iterations": len(result.history),
            "occupancy_error": last["occupancy_error"],
            "loss": last["loss"],
            "seconds": result.seconds,
            "seconds_per_iteration": result.seconds / len(result.history),
            **returns,
        }
        run.finish(metrics)
    return {"run": str(run.path), **metrics}


def tabular_policy_returns(mdp: TabularMDP, learned_reward: np.ndarray, *, discount: float) -> dict[str, float]:
    """True expected returns of the policies soft-optimal for the learned and the true reward,
    of the uniform policy, and the learned one normalised between them."""
    dynamics = Dynamics.of(mdp.transition)
    learned = expected_return(dynamics, mdp, soft_optimal_policy(mdp, learned_reward, discount=discount))
    expert = expected_return(dynamics, mdp, soft_optimal_policy(mdp, discount=discount))
    random = expected_return(dynamics, mdp, np.full((mdp.horizon, mdp.n_states, mdp.n_actions), 1.0 / mdp.n_actions))
    return {"learned_policy_return": learned, "expert_return": expert, "random_return": random, "normalized_return": (learned - random) / (expert - random)}


def gcl_job(
    demos: list[str], env_id: str, config: GCLConfig, ppo_config: PPOConfig, out: str | os.PathLike, *, progress: bool = True,
    resume: bool = False,
) -> dict[str, Any]:
    """Guided cost learning on `demos` into run directory `out`: the reward model (for `train ppo
    --reward`) and the PPO policy trained alongside it. `resume` continues the interrupted run in
    `out`.partial from its checkpoint (PPO's, holding the reward learner's state too)."""
    ppo_config.validate()
    seed_everything(config.seed)
    with closing(make_env(env_id)) as env:
        dataset = DemoDataset(demos)
        _check_demos_fit_env(dataset, env)
        observation_space, action_space = env.observation_space, env.action_space
    transitions = transitions_to_torch(load_transitions(dataset, next_observations=True))
    reward = make_reward_model(
        observation_space, action_space, hidden_sizes=list(config.hidden_sizes), inputs=config.inputs,
        normalize_observations=isinstance(observation_space, gym.spaces.Box),
    )
    learner = GuidedCostLearning(reward, transitions, config, updates=-(-ppo_config.total_steps // (ppo_config.n_steps * ppo_config.n_envs)))

    with RunWriter(out, config={
        "kind": "reward", "env_id": env_id, "creator": f"imitation-mcap {__version__}", "demos": [str(p) for p in demos],
        "demo_fingerprints": _fingerprints(dataset), "irl": {"method": "gcl", **vars(config)}, "ppo": vars(ppo_config).copy(), "reward": reward.config.to_json(),
    }, resume=resume, resume_ignore=RESUME_IGNORE) as run, _resumable(run):

        def log(row: dict[str, float]) -> None:
            run.log({**row, **learner.history[-1]})

        checkpoints = Checkpointing(save=run.save_checkpoint, resume=run.resumed)
        result = train_ppo(ppo_config, rollout_rewards=learner, log=log, progress=progress, checkpoints=checkpoints)
        run.save_weights(reward_tensors(reward) | policy_tensors(result.policy))
        run.update_config(policy=result.policy.config.to_json())
        plot_curve(run.file("learning_curve.png"), run.history, x="step", ys=["return", "optimised_return"], title=f"GCL on {env_id}: PPO's returns")
        plot_curve(run.file("reward_curve.png"), run.history, x="step", ys=["reward_loss", "demo_accuracy", "sample_accuracy"], title=f"GCL on {env_id}: reward learning")
        with closing(make_env(env_id)) as env:
            evaluation = _final_evaluation(result.policy.cpu(), env)
        last = run.history[-1]
        metrics = {
            "env_id": env_id,
            "method": "gcl",
            "demo_episodes": len(dataset),
            "demo_return": float(np.mean([facts.episode_return for facts in dataset.episodes])),
            "steps": result.steps,
            "seconds": result.seconds,
            "reward_loss": last["reward_loss"],
            "demo_accuracy": last["demo_accuracy"],
            "sample_accuracy": last["sample_accuracy"],
            "final_train_return": last["return"],
            "eval": evaluation,
        }
        run.finish(metrics)
    return {"run": str(run.path), **metrics}
