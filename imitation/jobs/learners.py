"""The `train` learners, one entry each: how it trains from the parsed command line and what it
prints, and a sweep's default metric. The command line runs every `train` command
through this table (its flags are declared with the command in imitation/commands.py), and sweeps
read their default metric from it. A new learner is its modules, its command's declaration and one
`register(TrainLearner(...))`.

Light on purpose, like the configs (each job is imported when its learner trains): the command
line reads it to build its parser.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from imitation import flags
from imitation.algorithms.adversarial_config import DISCRIMINATOR_TRAINING, AdversarialConfig
from imitation.algorithms.bc_config import BCConfig
from imitation.algorithms.dagger_config import DAggerConfig
from imitation.algorithms.policy_gradient_config import PGConfig
from imitation.algorithms.policy_search_config import SearchConfig
from imitation.algorithms.ppo_config import PPOConfig
from imitation.errors import ImitationError
from imitation.flags import given
from imitation.jobs.irl_methods import IRL_METHODS, RETURN, IRLRun
from imitation.ray_engine import requested_workers

Result = dict[str, Any]


@dataclass(frozen=True)
class Trained:
    """A job's result (printed as one JSON object with --json), and the lines printed without it
    (worded only then)."""

    result: Result
    lines: Callable[[], list[str]]


@dataclass(frozen=True)
class TrainLearner:
    """One `train NAME` command: `train(args)` runs its job from the parsed command line (None
    where this process has nothing to report: a torchrun process other than rank 0), `metric` is
    what a sweep optimises unless told (None: the sweep must say; `train irl`'s depends on the
    method, `imitation.jobs.irl_methods`)."""

    name: str
    train: Callable[[argparse.Namespace], Trained | None]
    metric: tuple[str, str, str] | None = RETURN


LEARNERS: dict[str, TrainLearner] = {}


def register(learner: TrainLearner) -> None:
    """Add the learner of `train NAME` (a later one of the same name replaces it)."""
    LEARNERS[learner.name] = learner


def _workers(args: argparse.Namespace) -> Any:
    return requested_workers(args.workers, args.ray_address, args.cpus)


def _evaluation(result: Result) -> str:
    evaluation = result["eval"]
    return f"eval return {evaluation['mean_return']:.1f} ± {evaluation['std_return']:.1f}"


def _train_ppo(args: argparse.Namespace) -> Trained:
    from imitation.envs.pixels import PixelRecipe
    from imitation.jobs.ppo import train_ppo

    pixels = (
        {"pixels": PixelRecipe.parse(args.pixels, grayscale=args.grayscale, crop=args.crop).to_json()} if args.pixels else {}
    )
    fields = given(args, PPOConfig)
    config, result = train_ppo(
        fields.pop("env_id"),
        args.out,
        fields | pixels,
        reward_run=args.reward,
        shaped=args.shaped,
        resume=args.resume,
        progress=not args.quiet,
        workers=_workers(args),
    )
    return Trained(
        result,
        lambda: [
            f"trained PPO ({config.objective}) on {args.env} for {result['steps']} steps in {result['seconds']:.0f} s "
            f"({result['steps_per_second']:.0f} steps/s); {_evaluation(result)}; run: {result['run']}"
        ],
    )


def _train_pg(args: argparse.Namespace) -> Trained:
    from imitation.jobs.pg import pg_config, pg_job

    config = pg_config(**given(args, PGConfig))
    result = pg_job(config, args.out, progress=not args.quiet, resume=args.resume)
    return Trained(
        result,
        lambda: [
            f"trained policy gradient ({config.estimator}) on {args.env} for {result['steps']} steps in "
            f"{result['batches']} batches, {result['seconds']:.0f} s; {_evaluation(result)}; run: {result['run']}"
        ],
    )


def _train_search(args: argparse.Namespace) -> Trained:
    from imitation.jobs.search import search_config, search_job

    config = search_config(method=args.algorithm, **given(args, SearchConfig))
    result = search_job(config, args.out, progress=not args.quiet, resume=args.resume)
    kept = "incumbent" if args.algorithm == "hill-climb" else "mean"
    return Trained(
        result,
        lambda: [
            f"searched {result['parameters']} policy parameters by {args.algorithm} on {args.env}: {result['steps']} steps, "
            f"{result['generations']} generations in {result['seconds']:.0f} s; eval return of the {kept} "
            f"{result['eval']['mean_return']:.1f} ± {result['eval']['std_return']:.1f}; run: {result['run']}"
        ],
    )


def _train_bc(args: argparse.Namespace) -> Trained | None:
    from imitation.jobs.bc import bc_job

    config = BCConfig(**given(args, BCConfig))
    result = bc_job(args.demos, args.env, config, args.out, progress=not args.quiet, resume=args.resume)
    if "run" not in result:  # a torchrun process other than rank 0, which reports the run
        return None

    def lines() -> list[str]:
        if result["offline"]:
            shown = [
                f"trained BC offline (no --env, so no rollouts) on {result['train_transitions']} transitions for "
                f"{result['epochs']} epochs (best {result['best_epoch']}); validation loss "
                f"{result['best_validation_loss']:.4f} on {result['validation_transitions']} held-out transitions; "
                f"run: {result['run']}"
            ]
        else:
            shown = [
                f"trained BC on {result['train_transitions']} transitions for {result['epochs']} epochs (best "
                f"{result['best_epoch']}, validation loss {result['best_validation_loss']:.4f}); {_evaluation(result)}; "
                f"run: {result['run']}"
            ]
        if result["validation"] is not None:
            shown.append(_yardstick_line(result["validation"], result["baselines"], result["beats_baselines"]))
        return shown

    return Trained(result, lines)


def _yardstick_line(scores: dict[str, float], baselines: dict[str, dict[str, float]], beats: dict[str, bool]) -> str:
    """BC beside the trivial baselines, on the held-out transitions, in one line."""

    def shown(values: dict[str, float]) -> str:
        return ", ".join(f"{key.replace('_', ' ')} {value:.4g}" for key, value in values.items())

    rows = "; ".join(
        f"{name.replace('_', '-')} {shown(values)} ({'beaten' if beats[name] else 'NOT beaten'})"
        for name, values in baselines.items()
    )
    return f"held-out: BC {shown(scores)}; baselines: {rows}"


def _train_dagger(args: argparse.Namespace) -> Trained:
    from imitation.envs.pixels import PixelRecipe
    from imitation.jobs.dagger import dagger_job

    config = DAggerConfig(**given(args, DAggerConfig))
    result = dagger_job(
        args.env,
        args.expert,
        config,
        args.out,
        demos=args.demos,
        pixels=PixelRecipe.parse(args.pixels, grayscale=args.grayscale, crop=args.crop) if args.pixels else None,
        speed=args.speed,
        progress=not args.quiet,
        resume=args.resume,
        workers=_workers(args),
    )

    def lines() -> list[str]:
        returns = ", ".join(f"{value:.1f}" for value in result["round_returns"])
        shown = [
            f"DAgger on {args.env} with expert {args.expert}: {result['rounds']} rounds, {result['expert_labels']} expert "
            f"labels; return by round: {returns}; {_evaluation(result)}; run: {result['run']}"
        ]
        if config.mode == "takeover":
            rates = ", ".join(f"{100 * rate:.1f} %" for rate in result["intervention_rates"])
            shown.append(f"intervention rate by round (share of steps the expert drove): {rates}")
        return shown

    return Trained(result, lines)


def _irl_run(args: argparse.Namespace) -> IRLRun:
    """What `train irl` was asked, refused in one line where a flag does not go with its --method."""
    method = IRL_METHODS[args.method]
    if args.workers is not None and not method.rollouts:
        raise ImitationError(f"--workers: --method {args.method} has no PPO rollouts to spread; use it with gcl, airl or gail")
    if args.gail_reward is not None and args.method != "gail":
        raise ImitationError(f"--gail-reward: chooses GAIL's reward, and --method {args.method} is not gail")
    for name in given(args, AdversarialConfig, only=DISCRIMINATOR_TRAINING):
        if not method.discriminator:
            raise ImitationError(
                f"{flags.flag_of(args.configs, 'AdversarialConfig', name)}: sets the training of GAIL's and AIRL's "
                f"discriminator, and --method {args.method} has none"
            )
    if args.warm_start is not None and not method.discriminator:
        raise ImitationError(f"--warm-start: starts GAIL's and AIRL's discriminator, and --method {args.method} has none")
    return IRLRun(
        args.method,
        args.demos,
        args.env,
        args.out,
        {config: given(args, config, only) for config, only in method.configs},
        seed=args.seed,
        progress=not args.quiet,
        resume=args.resume,
        workers=_workers(args),
        warm_start=args.warm_start,
    )


def _train_irl(args: argparse.Namespace) -> Trained:
    run = _irl_run(args)
    method = IRL_METHODS[args.method]
    result = method.train(run)
    return Trained(result, lambda: [method.describe(run, result)])


register(TrainLearner("ppo", _train_ppo))
register(TrainLearner("pg", _train_pg))
for _search in ("hill-climb", "cem", "cmaes"):
    register(TrainLearner(_search, _train_search))
register(TrainLearner("bc", _train_bc, metric=("validation_loss", "min", "best")))
register(TrainLearner("dagger", _train_dagger))
register(TrainLearner("irl", _train_irl, metric=None))
