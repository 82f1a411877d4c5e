"""`train irl`: maximum-entropy IRL into a reward run directory, tabular (maxent, mce) or
sample-based with PPO alongside (guided cost learning, and the adversarial GAIL and AIRL)."""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable
from contextlib import closing
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np

from imitation.algorithms.adversarial import AdversarialConfig, AdversarialImitation, Discriminator
from imitation.algorithms.airl import AIRLDiscriminator
from imitation.algorithms.gail import GAIL_OUTPUTS, GAILDiscriminator
from imitation.algorithms.gcl import GCLConfig, GuidedCostLearning
from imitation.algorithms.maxent_irl import MaxEntIRL, MaxEntIRLConfig, all_state_rewards, demo_visitation
from imitation.algorithms.ppo import PPO, PPOConfig
from imitation.algorithms.ray_rollouts import RayRollouts
from imitation.data.dataset import DemoDataset
from imitation.data.loader import TransitionTensors, check_episodes_finite, load_transitions, transitions_to_torch
from imitation.data.spaces import short_repr
from imitation.data.types import Transitions
from imitation.envs.make import make_env
from imitation.envs.pixels import PIXELS_KEY, image_keys, recorded_pixels, stack_frames, stacked_space
from imitation.envs.tabular import tabular_mdp_of
from imitation.envs.tabular_planning import soft_optimal_returns
from imitation.envs.vector import make_observed_env
from imitation.errors import ImitationError
from imitation.evaluation.plots import plot_curve, plot_grid_maps
from imitation.jobs.loop import Learner
from imitation.jobs.loop import run as run_learner
from imitation.jobs.run_config import RunConfig, config_json
from imitation.jobs.run_directory import check_demos_fit_env, checkpointing, final_evaluation, fingerprints, training_run
from imitation.policies import acting_env, make_acting_env, policy_tensors
from imitation.ray_engine import Workers, worker_session
from imitation.rewards import RewardNet, RewardRun, make_reward_model, potential_tensors, reward_tensors
from imitation.runs import read_run
from imitation.seeding import seed_everything


def tabular_irl_job(
    demos: list[str],
    env_id: str,
    config: MaxEntIRLConfig,
    out: str | os.PathLike,
    *,
    progress: bool = True,
    resume: bool = False,
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
        check_demos_fit_env(dataset, env)
        observation_space, action_space = env.observation_space, env.action_space
    demo_episodes = dataset.read_episodes()
    check_episodes_finite(demo_episodes, dataset)
    occupancy_target = demo_visitation(demo_episodes, n_states=mdp.n_states, horizon=mdp.horizon, discount=config.discount)
    model = make_reward_model(
        observation_space, action_space, feature_table=mdp.features, hidden_sizes=list(config.hidden_sizes)
    )

    run_config = RunConfig(
        kind="reward",
        env_id=env_id,
        demos=[str(p) for p in demos],
        demo_fingerprints=fingerprints(dataset),
        irl=config_json(config),
        reward=model.config.to_json(),
    )
    with training_run(out, run_config, x_axis="iteration", resume=resume) as run:
        learner = MaxEntIRL(mdp, occupancy_target, model, config)
        run_learner(learner, checkpoints=checkpointing(run), log=run.log, progress=progress)
        seconds = learner.clock.seconds  # training only, not the evaluation below
        run.save_weights(reward_tensors(model))
        learned_reward = all_state_rewards(model, mdp.n_states).detach().double().numpy()
        returns = soft_optimal_returns(mdp, learned_reward, discount=config.discount)
        plot_curve(
            run.file("irl_curve.png"),
            run.history,
            x="iteration",
            ys=["loss", "occupancy_error"],
            title=f"{config.method} IRL on {env_id}",
        )
        if mdp.grid_shape is not None:
            plot_grid_maps(
                run.file("reward_maps.png"),
                {"true reward": mdp.reward, "learned reward": learned_reward},
                grid_shape=mdp.grid_shape,
                title=env_id,
            )
            # Set by every iteration; a run (resumed or not) takes at least one, as checkpoints are never of a finished one.
            assert learner.occupancy is not None
            plot_grid_maps(
                run.file("occupancy_maps.png"),
                {"demos' visitation": occupancy_target, "learned visitation": learner.occupancy},
                grid_shape=mdp.grid_shape,
                title=env_id,
            )
        last = run.history[-1]
        metrics = {
            "env_id": env_id,
            "method": config.method,
            "demo_episodes": len(dataset),
            "iterations": len(run.history),
            "occupancy_error": last["occupancy_error"],
            "loss": last["loss"],
            "seconds": seconds,
            "seconds_per_iteration": seconds / len(run.history),
            **returns,
        }
        run.finish(metrics)
    return {"run": str(run.path), **metrics}


def gcl_job(
    demos: list[str],
    env_id: str,
    config: GCLConfig,
    ppo_config: PPOConfig,
    out: str | os.PathLike,
    *,
    progress: bool = True,
    resume: bool = False,
    workers: Workers | None = None,
) -> dict[str, Any]:
    """Guided cost learning on `demos` into run directory `out`: the reward model (for `train ppo
    --reward`) and the PPO policy trained alongside it (the maximum-entropy sampler, not meant
    for use). `resume` continues the interrupted run in `out`.partial from its checkpoint (PPO's,
    holding the reward learner's state too).

    Demos recorded with `record --pixels` are learnt from their frames alone: the reward reads
    the "pixels" leaf through a CNN, stacked as recorded (`--frame-stack`), and PPO acts in the env
    rendered the same way."""
    config.validate()

    def make(observation_space: gym.Space, action_space: gym.Space, options: dict[str, Any]) -> _Method:
        reward = make_reward_model(
            observation_space, action_space, hidden_sizes=list(config.hidden_sizes), inputs=config.inputs, **options
        )
        return _Method(
            name="gcl",
            config=config_json(config),
            reward=reward,
            learner=lambda ppo, transitions: GuidedCostLearning(ppo, reward, transitions, config),
            loss="reward_loss",
        )

    return _irl_with_ppo(demos, env_id, config.seed, ppo_config, out, make, progress=progress, resume=resume, workers=workers)


def adversarial_job(
    demos: list[str],
    env_id: str,
    config: AdversarialConfig,
    ppo_config: PPOConfig,
    out: str | os.PathLike,
    *,
    progress: bool = True,
    resume: bool = False,
    workers: Workers | None = None,
    warm_start: str | os.PathLike | None = None,
) -> dict[str, Any]:
    """GAIL or AIRL (`config.method`) on `demos` into run directory `out`: the imitating PPO policy
    (for `eval policy`) and the reward (AIRL's g, or GAIL's −log(1 − D)) for `train ppo --reward`
    and `eval reward`. `resume` continues the interrupted run in `out`.partial. Pixel demos are
    learnt from their frames, as in `gcl_job`. `warm_start`, a finished run of the same method and
    networks, gives the discriminator its start (weights and observation statistics); the policy
    starts fresh."""
    config.validate()

    def make(observation_space: gym.Space, action_space: gym.Space, options: dict[str, Any]) -> _Method:
        def net(inputs: str, hidden_sizes: list[int], output: str = "linear") -> RewardNet:
            return make_reward_model(
                observation_space, action_space, hidden_sizes=list(hidden_sizes), inputs=inputs, output=output, **options
            )

        discriminator: Discriminator
        potential = None
        if config.method == "gail":
            discriminator = GAILDiscriminator(net(config.reward_inputs, config.hidden_sizes, GAIL_OUTPUTS[config.gail_reward]))
        else:
            potential = net("s", config.potential_hidden_sizes)
            discriminator = AIRLDiscriminator(
                net(config.reward_inputs, config.hidden_sizes),
                potential,
                gamma=ppo_config.gamma,
                policy_entropy=config.policy_entropy,
            )
        if warm_start is not None:
            start_discriminator_from(discriminator, warm_start, config.method, env_id)
        return _Method(
            name=config.method,
            config=config_json(config) | ({"warm_start": str(warm_start)} if warm_start is not None else {}),
            reward=discriminator.recovered_reward(),
            potential=potential,
            learner=lambda ppo, transitions: AdversarialImitation(
                ppo, discriminator, transitions, config, fit_statistics=warm_start is None
            ),
            loss="discriminator_loss",
        )

    return _irl_with_ppo(demos, env_id, config.seed, ppo_config, out, make, progress=progress, resume=resume, workers=workers)


def start_discriminator_from(discriminator: Discriminator, run: str | os.PathLike, method: str, env_id: str) -> None:
    """`discriminator`'s networks (AIRL's g and h, GAIL's D) set to those `run`, a finished `train
    irl --method <method>` run on `env_id`, saved; one-line errors for any other run."""
    saved, weights = read_run(run)
    section = saved.get("irl")
    saved_method = section.get("method") if isinstance(section, dict) else None
    if saved_method != method:
        raise ImitationError(
            f"{run}: --warm-start needs a finished `train irl --method {method}` run, not a {saved_method!r} one"
        )
    if saved.get("env_id") != env_id:
        raise ImitationError(f"{run}: --warm-start: its discriminator learnt {saved.get('env_id')!r}, not {env_id}")
    reward_run = RewardRun.of(run, saved, weights)
    loaded = [reward_run.reward, *([reward_run.potential()] if method == "airl" else [])]
    names = ("g", "h") if method == "airl" else ("D",)
    for net, start, name in zip(discriminator.reward_nets(), loaded, names, strict=True):
        ours, theirs = net.config.to_json(), start.config.to_json()
        differing = [key for key in ours if ours[key] != theirs.get(key)]
        if differing:
            raise ImitationError(
                f"{run}: --warm-start: its {name} network's {differing[0]} is {short_repr(theirs.get(differing[0]))}, this "
                f"run's {short_repr(ours[differing[0]])}"
            )
        net.load_state_dict(start.state_dict())


@dataclass
class _Method:
    """What a PPO-based IRL method brings to `_irl_with_ppo`: its name and config (for
    config.json), the reward it exports, its learner over PPO, and the name of its loss."""

    name: str
    config: dict[str, Any]
    reward: RewardNet
    learner: Callable[[PPO, TransitionTensors], Learner]
    loss: str
    potential: RewardNet | None = None  # AIRL's h, saved beside g for `train ppo --reward RUN --shaped`


def _irl_with_ppo(
    demos: list[str],
    env_id: str,
    seed: int,
    ppo_config: PPOConfig,
    out: str | os.PathLike,
    make_method: Callable[[gym.Space, gym.Space, dict[str, Any]], _Method],
    *,
    progress: bool,
    resume: bool,
    workers: Workers | None,
) -> dict[str, Any]:
    """The run of an IRL method that learns alongside PPO: demos loaded (with their frames and
    stack when recorded with `record --pixels`), the method's learner run, the reward and PPO's
    policy saved, the curves plotted and the policy evaluated."""
    ppo_config.validate()
    seed_everything(seed)
    dataset = DemoDataset(demos)
    first = dataset.files[0]
    pixels, frames = recorded_pixels(first.user_metadata, str(first.path))
    if pixels is not None:
        ppo_config = dataclasses.replace(ppo_config, pixels=pixels.to_json(), frame_stack=frames)
    with closing(make_observed_env(env_id, pixels)) as env:
        check_demos_fit_env(dataset, env)
        observation_space, action_space = stacked_space(env.observation_space, frames), env.action_space
    loaded = load_transitions(dataset, next_observations=True)
    transitions = transitions_to_torch(with_frame_stacks(loaded, frames, image_keys(env.observation_space)))
    options: dict[str, Any] = (
        {"observation_keys": [PIXELS_KEY], "frame_stack": frames, "pixels": pixels.to_json()}
        if pixels is not None
        else {"normalize_observations": isinstance(observation_space, gym.spaces.Box) and not image_keys(observation_space)}
    )
    method = make_method(observation_space, action_space, options)
    run_config = RunConfig(
        kind="reward",
        env_id=env_id,
        demos=[str(p) for p in demos],
        demo_fingerprints=fingerprints(dataset),
        irl={"method": method.name, **method.config},
        ppo=config_json(ppo_config),
        reward=method.reward.config.to_json(),
        potential=method.potential.config.to_json() if method.potential is not None else None,
    )
    title = f"{method.name.upper()} on {env_id}"
    remote = RayRollouts(ppo_config.n_envs, workers.count) if workers else None
    with training_run(out, run_config, resume=resume) as run, worker_session(workers):
        ppo = PPO(ppo_config, remote=remote)
        try:
            learner = method.learner(ppo, transitions)
            run_learner(learner, checkpoints=checkpointing(run), log=run.log, progress=progress)
            seconds = ppo.clock.seconds  # training only, not the evaluation below
        finally:
            ppo.close()
        potential = potential_tensors(method.potential) if method.potential is not None else {}
        run.save_weights(reward_tensors(method.reward) | potential | policy_tensors(ppo.policy))
        run.update_config(policy=ppo.policy.config.to_json())
        plot_curve(
            run.file("learning_curve.png"),
            run.history,
            x="step",
            ys=["return", "optimised_return"],
            title=f"{title}: PPO's returns",
        )
        plot_curve(
            run.file("reward_curve.png"),
            run.history,
            x="step",
            ys=[method.loss, "demo_accuracy", "sample_accuracy"],
            title=f"{title}: reward learning",
        )
        policy = ppo.policy.cpu()
        with closing(make_acting_env(policy.config, env_id)) as env:  # rendering frames for a pixel policy
            evaluation = final_evaluation(policy, acting_env(policy, env))
        last = run.history[-1]
        metrics = {
            "env_id": env_id,
            "method": method.name,
            "demo_episodes": len(dataset),
            "demo_return": float(np.mean([facts.episode_return for facts in dataset.episodes])),
            "steps": ppo.global_step,
            "seconds": seconds,
            method.loss: last[method.loss],
            "demo_accuracy": last["demo_accuracy"],
            "sample_accuracy": last["sample_accuracy"],
            "final_train_return": last["return"],
            "eval": evaluation,
        }
        run.finish(metrics)
    return {"run": str(run.path), **metrics}


def recorded_observation(demos: list[str]) -> dict[str, Any]:
    """How GCL's PPO observes the env of `demos`, as PPOConfig fields: the frames and stack they
    were recorded with (`record --pixels`), none for other demos. Known before the PPOConfig is
    made, they choose its preset (`presets.ppo_config`)."""
    first = DemoDataset(demos).files[0]
    pixels, frames = recorded_pixels(first.user_metadata, str(first.path))
    return {"pixels": pixels.to_json(), "frame_stack": frames} if pixels is not None else {}


def with_frame_stacks(transitions: Transitions, frames: int, keys: list[str]) -> Transitions:
    """Stored transitions (single frames, rows in episode and time order) with each image leaf
    `keys` of s_t as the stack `StackFrames` shows, [x_{t-k+1}, …, x_t], and of s_{t+1} as the
    stack after it, [x_{t-k+2}, …, x_{t+1}]: s_t's stack shifted by one frame."""
    if frames == 1:
        return transitions
    observations = stack_frames(transitions.observations, transitions.episode_index, frames, keys)
    following = transitions.next_observations
    assert following is not None  # loaded with next_observations=True

    def shifted(stack: Any, frame: Any) -> np.ndarray:
        return np.concatenate([stack[:, 1:], frame[:, None]], axis=1)

    next_observations: Any
    if isinstance(observations, dict):
        next_observations = {
            key: shifted(value, following[key]) if key in keys else following[key] for key, value in observations.items()
        }
    else:
        next_observations = shifted(observations, following)
    return dataclasses.replace(transitions, observations=observations, next_observations=next_observations)
