"""`train dagger`: DAgger with an expert into a run directory, its rounds as MCAP files."""

from __future__ import annotations

import functools
import os
from contextlib import ExitStack
from typing import Any

import gymnasium as gym

from imitation.algorithms.bc import policy_options
from imitation.algorithms.dagger import DAgger, DAggerConfig, Policy
from imitation.algorithms.ray_dagger import RayRounds
from imitation.data.dataset import DemoDataset
from imitation.envs.pixels import PIXELS_KEY, PixelObservation, PixelRecipe, StackFrames, expert_on_state
from imitation.errors import ConfigError, ImitationError
from imitation.evaluation.plots import plot_curve
from imitation.evaluation.policy import EVAL_SEED, evaluate_policy
from imitation.experts.load import close_expert, load_expert, make_env_for_expert
from imitation.jobs.bc import bc_policy_kind
from imitation.jobs.loop import run as run_learner
from imitation.jobs.run_config import RunConfig, config_json
from imitation.jobs.run_directory import check_demos_fit_env, checkpointing, final_evaluation, fingerprints, training_run
from imitation.policies import SingleObservationPolicy, policy_tensors
from imitation.policy_kinds import build_policy
from imitation.policy_protocol import ImitationPolicy
from imitation.ray_engine import Workers
from imitation.seeding import seed_everything


def dagger_job(
    env_id: str,
    expert_spec: str,
    config: DAggerConfig,
    out: str | os.PathLike,
    *,
    demos: list[str] | None = None,
    pixels: PixelRecipe | None = None,
    speed: float = 1.0,
    progress: bool = True,
    resume: bool = False,
    workers: Workers | None = None,
) -> dict[str, Any]:
    """DAgger with `expert_spec` into run directory `out`; each round's labelled rollouts are
    written to `out/rounds/round-NN.mcap`. `resume` continues the interrupted run in
    `out`.partial from its checkpoint, with the rounds it had finished.

    With `pixels` the learner sees rendered frames (stacks of `config.bc.frame_stack`) and the
    expert the env's own observation beside them. With `workers`, each round's episodes are
    played by that many Ray workers, each into its own shard (`imitation.algorithms.ray_dagger`)."""
    if config.bc.previous_action == "on":
        raise ConfigError(
            "previous_action",
            "is for BC on a recorded command stream; DAgger's learner acts on the state alone",
            owner="BCConfig",
        )
    for name in ("image_size", "crop"):
        if getattr(config.bc, name) is not None:
            raise ConfigError(
                name,
                "resizes stored frames for train bc; DAgger renders its frames as --pixels and --crop say",
                owner="BCConfig",
            )
    demos = demos or []
    seed_everything(config.seed)
    frames = config.bc.frame_stack or 1
    if frames > 1 and pixels is None:
        raise ConfigError("frame_stack", "stacks rendered frames: give --pixels too", owner="BCConfig")
    config.validate()
    bc_policy_kind(config.bc)
    env, expert = env_and_expert(env_id, expert_spec, pixels, frames, seed=config.seed, speed=speed)
    if config.mode == "takeover" and not hasattr(expert, "engaged"):
        raise ConfigError(
            "mode",
            f"takeover needs an expert that takes the controls (standin, keyboard, gamepad, pointer), not {expert_spec}",
            owner="DAggerConfig",
        )
    if workers is not None and (config.mode == "takeover" or hasattr(expert, "show_status")):
        close_expert(expert)
        env.close()
        raise ImitationError(
            f"--workers: expert {expert_spec} drives at this machine (take-over or a person's window); "
            "its rounds run in this process, without --workers"
        )
    pixel_options: dict[str, Any] = {}
    metadata: dict[str, Any] = {}
    if pixels is not None:
        pixel_options = {
            "frame_stack": frames,
            "observation_keys": config.bc.observation_keys or [PIXELS_KEY],
            "cnn": config.bc.cnn,
            "pixels": pixels.to_json(),
        }
        metadata = {"pixels": pixels.to_json() | {"frame_stack": frames}}
    given = DemoDataset(demos) if demos else None
    if given is not None:
        check_demos_fit_env(given, env.env if isinstance(env, StackFrames) else env)
    policy = build_policy(
        config.bc.policy, env.observation_space, env.action_space, **policy_options(config.bc), **pixel_options
    )
    config.bc.validate(policy.is_continuous)

    def env_return(candidate: ImitationPolicy) -> float:
        return evaluate_policy(SingleObservationPolicy(candidate), env, episodes=5, seed=EVAL_SEED)["mean_return"]

    run_config = RunConfig(
        kind="dagger",
        env_id=env_id,
        expert=expert_spec,
        demos=[str(p) for p in demos],
        demo_fingerprints=fingerprints(given),
        dagger=config_json(config),
        policy=policy.config.to_json(),
    )
    with ExitStack() as cleanup, training_run(out, run_config, x_axis="round", resume=resume) as run:
        cleanup.callback(env.close)
        cleanup.callback(close_expert, expert)  # a person's window
        remote = None
        if workers is not None:
            cleanup.enter_context(workers.session())
            make = functools.partial(env_and_expert, env_id, expert_spec, pixels, frames, seed=config.seed)
            remote = RayRounds(
                workers.count,
                make,
                round_dir=run.file("rounds"),
                env_id=env_id,
                mode=config.mode,
                seed=config.seed,
                metadata=metadata,
            )
            cleanup.callback(remote.close)
        learner = DAgger(
            env,
            expert,
            policy,
            config,
            round_dir=run.file("rounds"),
            env_id=env_id,
            demos=demos,
            evaluate=env_return,
            metadata=metadata,
            remote=remote,
        )
        # A round can be stopped midway, the first one too: --resume then starts from the checkpoint at the start.
        run_learner(learner, checkpoints=checkpointing(run, at_start=True), log=run.log, progress=progress)
        run.save_weights(policy_tensors(learner.policy.cpu()))
        plot_curve(
            run.file("return_curve.png"),
            run.history,
            x="expert_labels",
            ys=["return", "rollout_return"],
            title=f"DAgger on {env_id}",
        )
        if config.mode == "takeover":
            plot_curve(
                run.file("intervention_curve.png"),
                run.history,
                x="round",
                ys=["intervention_rate"],
                title=f"DAgger (take-over) on {env_id}: share of steps the expert drove",
            )
        plot_curve(
            run.file("loss_curve.png"),
            run.history,
            x="round",
            ys=["validation_loss"],
            title=f"DAgger on {env_id}: validation loss",
        )
        metrics = {
            "env_id": env_id,
            "expert": expert_spec,
            "rounds": len(run.history),
            "expert_labels": int(run.history[-1]["expert_labels"]),
            "round_returns": [row["return"] for row in run.history],
            "intervention_rates": [row["intervention_rate"] for row in run.history],
            "eval": final_evaluation(learner.policy.cpu(), env),
        }
        run.finish(metrics)
    return {"run": str(run.path), "round_files": [str(run.path / "rounds" / p.name) for p in learner.files], **metrics}


def env_and_expert(
    env_id: str, expert_spec: str, pixels: PixelRecipe | None, frames: int, *, seed: int, speed: float = 1.0
) -> tuple[gym.Env, Policy]:
    """The env DAgger's learner acts in and the expert that labels it: with `pixels`, rendered
    frames (stacks of `frames`) for the learner and the env's own observation for the expert.
    A Ray worker builds its own pair with it."""
    env = make_env_for_expert(env_id, expert_spec, pixels=pixels is not None)
    expert = load_expert(expert_spec, env, seed=seed, speed=speed)
    if pixels is None:
        return env, expert
    pixel_env = PixelObservation(env, pixels)
    return (StackFrames(pixel_env, frames) if frames > 1 else pixel_env), expert_on_state(expert, pixel_env)
