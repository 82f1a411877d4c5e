"""`train bc`: behavioural cloning on demo files into a run directory."""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Callable, Sequence
from contextlib import closing, nullcontext
from typing import Any

import gymnasium as gym
import numpy as np
import torch

from imitation.algorithms.bc import BCConfig, BehaviouralCloning, policy_options, training_step_bytes
from imitation.checkpoints import Tensors
from imitation.data.dataset import DemoDataset
from imitation.data.frame_transform import FrameTransform
from imitation.data.loader import (
    TransitionTensors,
    available_memory,
    human_steps,
    load_transitions,
    resolve_device,
    select_human_steps,
    split_episode_tails,
    split_episodes,
    transitions_to_torch,
)
from imitation.data.mcap.format import TIME_FIELD
from imitation.data.shards import Share, plan_shares
from imitation.data.spaces import space_leaves
from imitation.data.stream import StreamingLoader
from imitation.data.types import Transitions
from imitation.data.windows import WindowSpec
from imitation.encoders import CNNConfig
from imitation.envs.make import make_env
from imitation.envs.pixels import PIXELS_KEY, image_keys, make_pixel_env, recorded_pixels, stack_frames, stacked_space
from imitation.envs.previous_action import previous_action_space, with_previous_actions
from imitation.errors import ConfigError, ImitationError
from imitation.evaluation.baselines import baseline_scores, policy_scores
from imitation.evaluation.plots import plot_curve
from imitation.evaluation.policy import EVAL_SEED, evaluate_policy
from imitation.jobs.distributed import ProcessGroup, process_group, world_size
from imitation.jobs.loop import Checkpointing
from imitation.jobs.loop import run as run_learner
from imitation.jobs.run_config import RunConfig, config_json
from imitation.jobs.run_directory import check_demos_fit_env, checkpointing, final_evaluation, fingerprints, training_run
from imitation.observation_encoding import check_cnn_size, observation_layout
from imitation.policies import SingleObservationPolicy, acting_env, policy_tensors
from imitation.policy_kinds import PolicyKind, build_policy, policy_kind
from imitation.policy_protocol import ImitationPolicy
from imitation.progress import activity
from imitation.seeding import seed_everything


def bc_job(
    demos: list[str],
    env_id: str | None,
    config: BCConfig,
    out: str | os.PathLike,
    *,
    progress: bool = True,
    resume: bool = False,
) -> dict[str, Any]:
    """Behavioural cloning on `demos` into run directory `out`.

    Without `env_id` it trains offline (recordings with no simulator behind them): the policy
    takes the demos' own spaces and the run reports the validation loss only, no returns.
    `resume` continues the interrupted run in `out`.partial from its checkpoint.

    Under torchrun (WORLD_SIZE > 1) this is one of the processes of a data-parallel run: each
    loads its share of the demos by chunks (`imitation.data.shards`), the same split held out
    as by one process, and trains a replica (`BehaviouralCloning`'s `parallel`). Rank 0 writes
    the run and returns its result; the others write nothing and return {"rank": rank}."""
    processes = world_size()
    if processes == 1:
        return _bc_job(demos, env_id, config, out, progress=progress, resume=resume, parallel=None)
    config.validate_data_parallel(processes)  # before the processes meet
    with process_group(resolve_device(config.device)) as group:
        return _bc_job(demos, env_id, config, out, progress=progress and group.rank == 0, resume=resume, parallel=group)


def _bc_job(
    demos: list[str],
    env_id: str | None,
    config: BCConfig,
    out: str | os.PathLike,
    *,
    progress: bool,
    resume: bool,
    parallel: ProcessGroup | None,
) -> dict[str, Any]:
    """`bc_job` as one process, or as one of the data-parallel `parallel`."""
    kind = bc_policy_kind(config)  # refused before anything loads
    seed_everything(config.seed)
    dataset = DemoDataset(demos)
    first = dataset.files[0]
    pixels, frames = recorded_pixels(first.user_metadata, str(first.path), frame_stack=config.frame_stack)
    if env_id and pixels is not None:
        env: gym.Env | None = make_pixel_env(env_id, pixels)
    else:
        env = make_env(env_id) if env_id else None
    if env is not None:
        check_demos_fit_env(dataset, env)
    elif dataset.num_transitions == 0:
        raise ImitationError(f"{dataset.files[0].path}: the demos hold no transitions (no episode, or only empty ones)")
    spaces = env if env is not None else dataset
    # A sequence policy reads the actions of its history from its windows, not from its observation.
    previous_action = (config.previous_action == "on" or not kind.sequences) and _conditions_on_previous_action(
        config,
        spaces.observation_space,
        spaces.action_space,
        offline=env is None,
        recording=all(TIME_FIELD.topic in file.channels for file in dataset.files),
    )
    keys = image_keys(spaces.observation_space)
    if frames > 1 and not keys:
        raise ConfigError("frame_stack", "stacks image observations, and the demos hold none", owner="BCConfig")
    transform = config.frame_transform()
    if transform is not None:
        transform.check(dataset.observation_space, str(first.path))
    observed = transform.space(spaces.observation_space) if transform is not None else spaces.observation_space
    observation_space = (
        previous_action_space(observed, spaces.action_space)
        if previous_action
        else stacked_space(observed, frames)
        if frames > 1
        else observed
    )
    observation_keys = config.observation_keys or ([PIXELS_KEY] if pixels is not None else None)
    _check_training_memory(dataset, observation_space, spaces.action_space, config, keys=observation_keys, frames=frames)
    train: TransitionTensors | StreamingLoader
    validation: TransitionTensors | StreamingLoader | None
    if config.stream_memory is not None and config.steps == "human":
        raise ConfigError("steps", "human reads whole episodes; leave the streaming memory budget unset", owner="BCConfig")
    plan: list[Share] = []

    def share(counted: Sequence[int]) -> list[int]:
        """This process's episodes, the transitions of the `counted` ones balanced across the processes."""
        assert parallel is not None  # asked for only then
        plan[:] = plan_shares(dataset, parallel.world_size, counted=counted)
        return plan[parallel.rank].episodes

    if config.stream_memory is not None:
        # Stacked frames are images, which a sequence kind refuses itself when it is built (train-63).
        window = WindowSpec(config.history, config.chunk) if kind.sequences and frames == 1 else None
        train, validation, split = _streams(
            dataset,
            config,
            previous_action=previous_action,
            frames=frames,
            image_keys=keys,
            transform=transform,
            window=window,
        )
    else:
        resized = f", frames {transform.describe()} as they load" if transform is not None else ""
        what = f"loading {dataset.num_transitions} transitions of {len(dataset)} episode(s){resized}"
        with activity("BC", what, enabled=progress) as loading:
            observations = dataset.num_transitions + len(dataset)  # each episode's steps and its final observation
            train, validation, split = _split(
                dataset,
                config,
                offline=env is None,
                previous_action=previous_action,
                frames=frames,
                image_keys=keys,
                share=share if parallel is not None else None,
                transform=transform,
                loaded=(lambda n: loading.count(n, observations, "observations")) if loading is not None else None,
            )
    train_transitions = _transitions(train)
    validation_transitions = _transitions(validation) if validation is not None else 0
    if parallel is not None:
        train_transitions, validation_transitions = _pooled_counts(parallel, train_transitions, validation_transitions)
        if "train_transitions" in split:  # episode tails held out: the record counts every process's
            split |= {"train_transitions": train_transitions, "validation_transitions": validation_transitions}
    pixel_options = {
        "frame_stack": frames,
        "observation_keys": observation_keys,
        "cnn": config.cnn,
        "pixels": pixels.to_json() if pixels is not None else None,
        "image_transform": transform.to_json() if transform is not None else None,
    }
    config.validate(isinstance(spaces.action_space, gym.spaces.Box))  # the flags, before a policy is built from them
    try:
        policy = build_policy(
            config.policy,
            observation_space,
            spaces.action_space,
            previous_action=previous_action,
            **policy_options(config, train_transitions),
            **pixel_options,
        )
    except ImitationError as error:
        raise ImitationError(f"{f'--env {env_id}' if env is not None else dataset.files[0].path}: {error}") from None
    policy_env = acting_env(policy, env) if env is not None else None

    def env_return(candidate: ImitationPolicy) -> float:
        assert policy_env is not None  # passed to the learner only with an env
        return evaluate_policy(SingleObservationPolicy(candidate), policy_env, episodes=5, seed=EVAL_SEED)["mean_return"]

    run_config = RunConfig(
        kind="bc",
        env_id=env_id,
        offline=env is None,
        demos_env_id=dataset.env_id,
        demos=[str(p) for p in demos],
        demo_fingerprints=fingerprints(dataset),
        bc=config_json(config),
        policy=policy.config.to_json(),
        split=split,
        world_size=parallel.world_size if parallel is not None else None,
    )
    if parallel is not None and parallel.rank != 0:
        with closing(env) if env is not None else nullcontext():
            learner = BehaviouralCloning(policy, train, validation, config, parallel=parallel)
            resumed = parallel.broadcast_checkpoint(None) if resume else None
            run_learner(learner, checkpoints=Checkpointing(save=_written_by_rank_0, resume=resumed, agree=parallel.any))
        return {"rank": parallel.rank}
    with (
        closing(env) if env is not None else nullcontext(),
        training_run(out, run_config, x_axis="epoch", resume=resume) as run,
    ):
        streamed = isinstance(train, StreamingLoader) and bool(policy.observation_normalizers)
        with activity("BC", "fitting the normalisers in one pass over the demos", enabled=progress and streamed):
            learner = BehaviouralCloning(
                policy, train, validation, config, evaluate=env_return if env is not None else None, parallel=parallel
            )
        checkpoints = checkpointing(run)
        if parallel is not None:
            resumed = parallel.broadcast_checkpoint(checkpoints.resume) if resume else None
            checkpoints = dataclasses.replace(checkpoints, resume=resumed, agree=parallel.any)
        run_learner(learner, checkpoints=checkpoints, log=run.log, progress=progress)
        seconds = learner.clock.seconds  # training only, not the evaluation below
        with activity("BC", "scoring the trained policy", enabled=progress):
            run.save_weights(policy_tensors(learner.policy.cpu()))
            states = _states_alone(spaces.observation_space) if previous_action else _unchanged
            # Data-parallel: rank 0 holds its share alone, so no scores on the held-out transitions.
            yardstick = _yardstick(
                learner,
                train,
                validation,
                config,
                spaces.action_space,
                states,
                scored=parallel is None,
                previous_action=previous_action if _boxes(spaces.observation_space, spaces.action_space) else None,
                history=config.history,
            )
            title = f"BC on {env_id or dataset.env_id or 'offline demos'}"
            plot_curve(
                run.file("loss_curve.png"),
                run.history,
                x="epoch",
                ys=["train_loss", "validation_loss"],
                title=f"{title}: loss",
                references={f"{name} baseline": value for name, value in yardstick["references"].items()},
            )
            if env is not None:
                plot_curve(run.file("return_curve.png"), run.history, x="epoch", ys=["return"], title=f"{title}: return")
            metrics = {
                "env_id": env_id,
                "offline": env is None,
                "previous_action": previous_action,
                "train_transitions": train_transitions,
                "validation_transitions": validation_transitions,
                "data_parallel": _plan_summary(plan) if parallel is not None else None,
                "epochs": len(run.history),
                "best_epoch": learner.best_epoch,
                "best_validation_loss": min((row["validation_loss"] for row in run.history), default=None),
                "seconds": seconds,
                "samples_per_second": run.history[-1]["samples_per_second"],
                "stopped": yardstick["stopped"],
                "validation": yardstick["validation"],
                "baselines": yardstick["baselines"],
                "beats_baselines": yardstick["beats"],
                "warnings": yardstick["warnings"],
                "eval": final_evaluation(learner.policy.cpu(), policy_env) if policy_env is not None else None,
            }
            run.finish(metrics)
    return {"run": str(run.path), **metrics}


def _yardstick(
    learner: BehaviouralCloning,
    train: TransitionTensors | StreamingLoader,
    validation: TransitionTensors | StreamingLoader | None,
    config: BCConfig,
    action_space: gym.Space,
    states: Callable[[TransitionTensors], TransitionTensors],
    *,
    scored: bool = True,
    previous_action: bool | None = None,
    history: int = 1,
) -> dict[str, Any]:
    """How the run ended, and the policy beside the trivial baselines on the held-out transitions
    (`imitation.evaluation.baselines`, on the `states` alone where the policy saw x_t): scores, which
    baselines it beats (lower NLL and lower squared error or error rate), the baselines' values
    of the plotted loss, and what a user must be told: a baseline not beaten is quoted by the
    scores on which BC lost, and where that is hold, the other `previous_action` setting (None
    where the spaces cannot take one) is suggested, or, for a policy of `history` > 1 observations,
    said that it was scored on each observation alone (as at an episode's start). Streamed data is
    not scored, nor data not all `scored` here: the scores take all the held-out transitions in
    memory."""
    warnings = []
    if learner.stopped:
        stopped = f"no better validation loss for {config.patience} epochs (best at epoch {learner.best_epoch})"
    else:
        stopped = f"epoch limit ({config.epochs})"
        if learner.best_epoch > config.epochs - max(1, config.epochs // 20):
            warnings.append(
                f"BC stopped at its epoch limit ({config.epochs}) while the validation loss was still improving "
                f"(best at epoch {learner.best_epoch}): more epochs would likely fit better"
            )
    if not scored or validation is None or not len(validation) or isinstance(validation, StreamingLoader):
        return {"stopped": stopped, "validation": None, "baselines": {}, "beats": {}, "references": {}, "warnings": warnings}
    assert not isinstance(train, StreamingLoader)  # streamed validation goes with streamed training
    # A policy with a CNN scored in pieces of a training batch: its activations then take what a training step's did.
    rows = config.batch_size if learner.policy.reads_images else 1024
    scores = policy_scores(learner.policy.cpu(), validation.to("cpu"), rows=rows)
    baselines = baseline_scores(states(train), states(validation), action_space)
    # A kind without a likelihood is judged by the scores it has.
    beats = {
        name: all(scores[key] < value for key, value in baseline.items() if key in scores)
        for name, baseline in baselines.items()
    }
    loss = "mse" if config.loss == "mse" else "nll"
    references = {name: baseline[loss] for name, baseline in baselines.items() if loss in baseline}
    if beaten := [name for name, won in beats.items() if not won]:
        lost = "; ".join(
            (f"{name}: " if len(beaten) > 1 else "")
            + ", ".join(
                f"{_SCORE_NAMES.get(key, key)} {scores[key]:.4g} against {value:.4g}"
                for key, value in baselines[name].items()
                if key in scores and not scores[key] < value
            )
            for name in beaten
        )
        advice = ""
        if history > 1:
            advice = f"; the policy reads {history} observations and was scored on each alone, as at an episode's start"
        elif "hold" in beaten and previous_action is not None:
            advice = (
                "; try --previous-action off: the policy then sees the state alone"
                if previous_action
                else "; try --previous-action on: the policy then sees the previous action, as the hold baseline does"
            )
        warnings.append(
            f"BC does not beat the {', '.join(beaten)} baseline{'s' if len(beaten) > 1 else ''} on the held-out transitions "
            f"({lost}){advice}"
        )
    return {
        "stopped": stopped,
        "validation": scores,
        "baselines": baselines,
        "beats": beats,
        "references": references,
        "warnings": warnings,
    }


_SCORE_NAMES = {"nll": "NLL", "mse": "MSE", "error_rate": "error rate"}


def _boxes(observation_space: gym.Space, action_space: gym.Space) -> bool:
    """Whether a policy of these spaces can take the previous action as an input."""
    return isinstance(observation_space, gym.spaces.Box) and isinstance(action_space, gym.spaces.Box)


def _conditions_on_previous_action(
    config: BCConfig, observation_space: gym.Space, action_space: gym.Space, *, offline: bool, recording: bool = False
) -> bool:
    """Whether the policy is one of (s_t, a_{t-1}): config.previous_action, "auto" resolved (on
    offline, not streamed, for Box set-points, actions of the observations' shape, and for a
    `recording`: demos that keep a real clock's times, a ROS bag's command streams)."""
    boxes = _boxes(observation_space, action_space)
    if config.previous_action == "on" and not boxes:
        raise ConfigError(
            "previous_action",
            f"is for Box observations and actions, not {type(observation_space).__name__} and {type(action_space).__name__}",
            owner="BCConfig",
        )
    if config.previous_action != "auto":
        return config.previous_action == "on"
    set_points = observation_space.shape == action_space.shape
    return boxes and offline and config.stream_memory is None and (set_points or recording)


def _with_previous_actions(transitions: Transitions) -> Transitions:
    """x_t = [s_t, a_{t-1}, 1{t=0}] in place of s_t (rows in episode and time order, as loaded)."""
    assert isinstance(transitions.observations, np.ndarray) and isinstance(transitions.actions, np.ndarray)  # Box spaces
    observations = with_previous_actions(transitions.observations, transitions.actions, transitions.episode_index)
    return dataclasses.replace(transitions, observations=observations)


def _unchanged(transitions: TransitionTensors) -> TransitionTensors:
    return transitions


def _states_alone(observation_space: gym.Space) -> Callable[[TransitionTensors], TransitionTensors]:
    """Transitions of x_t (`_with_previous_actions`) → the same with s_t of `observation_space` alone."""
    shape = observation_space.shape or ()

    def states(transitions: TransitionTensors) -> TransitionTensors:
        assert isinstance(transitions.observations, torch.Tensor)  # x_t is a Box
        observations = transitions.observations[:, : int(np.prod(shape))].reshape(-1, *shape)
        return dataclasses.replace(transitions, observations=observations)

    return states


def _split(
    dataset: DemoDataset,
    config: BCConfig,
    *,
    offline: bool,
    previous_action: bool,
    frames: int = 1,
    image_keys: list[str] | None = None,
    share: Callable[[Sequence[int]], list[int]] | None = None,
    transform: FrameTransform | None = None,
    loaded: Callable[[int], None] | None = None,
) -> tuple[TransitionTensors, TransitionTensors | None, dict[str, Any]]:
    """Training and validation transitions: whole episodes held out; offline, where the
    validation loss is all a run reports, each episode's last steps when there are too few
    episodes to spare one (a single long recording). With `previous_action` the observations are
    x_t, built before the split so that a held-out tail starts from the command before it; so are
    stacks of `frames` frames of the `image_keys` leaves, after their frames are cropped and
    resized by `transform` as they load; `loaded(n)` is told of observations loaded.

    With `share` (a data-parallel process), the same split, of the episodes `share(counted)`
    gives this process for the training episodes `counted`; the split's record stays whole."""

    def load(episodes: list[int] | None = None) -> Transitions:
        transitions = load_transitions(
            dataset,
            episodes=episodes,
            next_observations=False,
            too_large=("resize the frames as they load (--image-size HxW), " if image_keys else "")
            + "stream them instead (--stream-memory MB), train on fewer demo files, or on a machine with more memory",
            transform=transform,
            progress=loaded,
        )
        if frames > 1:
            observations = stack_frames(transitions.observations, transitions.episode_index, frames, image_keys or [])
            transitions = dataclasses.replace(transitions, observations=observations)
        return _with_previous_actions(transitions) if previous_action else transitions

    def chosen(episodes: list[int], transitions: TransitionTensors) -> TransitionTensors:
        """With `steps="human"`, the steps a person drove."""
        return select_human_steps(transitions, dataset, episodes) if config.steps == "human" else transitions

    train_ids, validation_ids = split_episodes(len(dataset), validation_fraction=config.validation_fraction, seed=config.seed)
    if validation_ids or not offline or config.validation_fraction == 0:
        mine = set(share(train_ids)) if share is not None else None
        train_own = train_ids if mine is None else [k for k in train_ids if k in mine]
        validation_own = validation_ids if mine is None else [k for k in validation_ids if k in mine]
        train = chosen(train_own, transitions_to_torch(load(train_own)))
        validation = chosen(validation_own, transitions_to_torch(load(validation_own))) if validation_own else None
        _check_some_training(dataset, len(train))
        return train, validation, {"train_episodes": train_ids, "validation_episodes": validation_ids}
    own = share(range(len(dataset))) if share is not None else None
    every = load(own)
    train_rows, validation_rows = split_episode_tails(every, validation_fraction=config.validation_fraction)
    if config.steps == "human":
        person = human_steps(dataset, range(len(dataset)) if own is None else own)
        train_rows, validation_rows = train_rows[person[train_rows]], validation_rows[person[validation_rows]]
        _check_some_training(dataset, len(train_rows))
    tensors = transitions_to_torch(every)
    validation = tensors.select(torch.from_numpy(validation_rows)) if len(validation_rows) else None
    return (
        tensors.select(torch.from_numpy(train_rows)),
        validation,
        {
            "episode_tails": config.validation_fraction,
            "train_transitions": len(train_rows),
            "validation_transitions": len(validation_rows),
        },
    )


def _check_training_memory(
    dataset: DemoDataset,
    observation_space: gym.Space,
    action_space: gym.Space,
    config: BCConfig,
    *,
    keys: list[str] | None,
    frames: int,
) -> None:
    """Refuse, before the demos load or a weight is allocated, a CNN beyond the limit on its
    weights (`check_cnn_size`), or a policy and batch that will not fit beside the data
    (`training_step_bytes`, the demos at the size the policy reads them, or the streaming budget)
    in the memory available, where the demos alone would: one line saying which flag helps."""
    try:
        layout = observation_layout(observation_space, keys, frames)
        weights, step = training_step_bytes(
            observation_space, action_space, config, keys=keys, frames=frames, transitions=dataset.num_transitions
        )
    except ImitationError:
        return  # spaces no policy takes: building the policy says so, naming the demos
    images = layout.images if layout is not None else []
    if layout is not None and images:
        try:
            check_cnn_size(layout, CNNConfig.from_json(config.cnn or {}))
        except ImitationError as error:
            raise ImitationError(f"{dataset.files[0].path}: {error}") from None
    available = available_memory()
    row = sum(dtype.itemsize * math.prod(shape) for _, dtype, shape in space_leaves(observation_space))
    data = config.stream_memory if config.stream_memory is not None else dataset.num_transitions * row
    if available is None or step + data <= available or data > available:
        return  # it fits; or the demos alone do not, which their loading refuses with its own advice
    rows = min(config.batch_size, max(dataset.num_transitions, config.epoch_samples))
    sides = ", ".join(sorted({f"{leaf.height}×{leaf.width}" for leaf in images}))
    advice = (
        "train on smaller frames (--image-size 96x96 resizes them as they load) or take smaller batches (--batch-size)"
        if any(leaf.height * leaf.width > 128 * 128 for leaf in images)
        else "take smaller batches (--batch-size)"
    )
    raise ImitationError(
        f"{dataset.files[0].path}: a BC step on batches of {rows}{f' {sides} frames' if sides else ''} "
        f"needs about {step / 2**30:.1f} GiB ({weights} weights with their gradients and Adam's moments, and the "
        f"activations) beside {data / 2**30:.1f} GiB of demos, and {available / 2**30:.1f} GiB is available; {advice}"
    )


def _check_some_training(dataset: DemoDataset, transitions: int) -> None:
    """Refuse training on nothing: what is left when `--steps human` finds no person's step."""
    if not transitions:
        raise ImitationError(f"{dataset.files[0].path}: no step of the training episodes was driven by a person")


def _pooled_counts(parallel: ProcessGroup, *counts: int) -> list[int]:
    """Each of `counts` summed over the processes."""
    pooled = torch.tensor(counts, dtype=torch.float64)
    parallel.all_sum(pooled)
    return [int(count) for count in pooled.tolist()]


def _written_by_rank_0(tensors: Tensors, state: dict[str, Any]) -> None:
    """A data-parallel process other than rank 0 saves nothing: rank 0's checkpoint holds every
    process's place (`BehaviouralCloning.state_dict`)."""


def _plan_summary(plan: list[Share]) -> dict[str, Any]:
    """What metrics.json records of a data-parallel run's shares."""
    return {
        "world_size": len(plan),
        "shares": [
            {"episodes": len(share.episodes), "chunks": len(share.chunks), "train_transitions": share.transitions}
            for share in plan
        ],
    }


def bc_policy_kind(config: BCConfig) -> PolicyKind:
    """The registered kind `config.policy`; a ConfigError naming the setting of BC's that does not apply to it."""
    return policy_kind(
        config.policy,
        history=config.history,
        chunk=config.chunk,
        observation_noise=config.observation_noise,
        members=config.members,
    )


def _transitions(data: TransitionTensors | StreamingLoader) -> int:
    return data.transitions if isinstance(data, StreamingLoader) else len(data)


def _streams(
    dataset: DemoDataset,
    config: BCConfig,
    *,
    previous_action: bool,
    frames: int,
    image_keys: list[str],
    transform: FrameTransform | None = None,
    window: WindowSpec | None = None,
) -> tuple[StreamingLoader, StreamingLoader | None, dict[str, Any]]:
    """`_split` for `config.stream_memory`: whole episodes held out (never episode tails), each
    side streamed within the memory budget; validation in order, one batch at a time."""
    assert config.stream_memory is not None  # the caller streams only then
    if previous_action:
        raise ConfigError(
            "stream_memory", "streams no data for a policy of the previous action; leave it unset", owner="BCConfig"
        )
    train_ids, validation_ids = split_episodes(len(dataset), validation_fraction=config.validation_fraction, seed=config.seed)
    options: dict[str, Any] = {
        "batch_size": config.batch_size,
        "memory": config.stream_memory,
        "frames": frames,
        "image_keys": image_keys,
        "transform": transform,
        "window": window,
    }
    train = StreamingLoader(dataset, train_ids, seed=config.seed, min_samples=config.epoch_samples, **options)
    if train.transitions == 0:
        raise ImitationError("no transitions to load: the demos hold no steps")
    validation = StreamingLoader(dataset, validation_ids, shuffle=False, **options) if validation_ids else None
    return train, validation, {"train_episodes": train_ids, "validation_episodes": validation_ids}
