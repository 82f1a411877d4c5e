"""The `train` commands, one entry each: the command's declaration (help, description and the
dataclasses its flags come from, as in imitation/commands.py), how its learner trains from the
parsed command line and what it prints, and the metric a sweep of it optimises unless told. The
parser (`all_commands`), the one handler of every `train` command (`cli.cmd_train`) and sweeps
(`default_metric`) read this table: a new learner is its modules and one
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
from imitation.commands import (
    COMMANDS,
    BCOptions,
    Command,
    DAggerOptions,
    IRLOptions,
    Options,
    PersonSpeed,
    Pixels,
    PPOOptions,
    RayWorkers,
    RunOutput,
    pixels_helps,
    settings,
    workers_helps,
)
from imitation.errors import ImitationError
from imitation.flags import given
from imitation.jobs.irl_methods import DEFAULT_METHOD, IRL_METHODS, RETURN, IRLRun
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
    """One `train NAME` command: its declaration; `train(args)` runs its job from the parsed
    command line (None where this process has nothing to report: a torchrun process other than
    rank 0); `metric` is what a sweep optimises unless told: a column of the rows the learner logs
    (its progress.csv), whether lower or higher is better, and which of a trial's values is its
    result (BC keeps its best epoch's weights, the others end with their last). None: the sweep
    must say; `train irl`'s depends on the method (`imitation.jobs.irl_methods`)."""

    name: str
    command: Command
    train: Callable[[argparse.Namespace], Trained | None]
    metric: tuple[str, str, str] | None = RETURN


LEARNERS: dict[str, TrainLearner] = {}


def register(learner: TrainLearner) -> None:
    """Add the learner of `train NAME` (a later one of the same name replaces it)."""
    LEARNERS[learner.name] = learner


def all_commands() -> dict[str, Command]:
    """Every command by its words, the `train` ones (from this table) before `eval`."""
    words = list(COMMANDS)
    at = words.index("eval policy")
    train = {f"train {name}": learner.command for name, learner in LEARNERS.items()}
    return {word: COMMANDS[word] for word in words[:at]} | train | {word: COMMANDS[word] for word in words[at:]}


def default_metric(command: str, args: dict[str, Any]) -> tuple[str, str, str] | None:
    """The metric a sweep of `command` with fixed flags `args` optimises unless its file names
    one (`TrainLearner.metric`); for `train irl`, its method's, None for an unknown one."""
    if command != "train irl":
        learner = LEARNERS.get(command.removeprefix("train "))
        return learner.metric if learner is not None else None
    method = IRL_METHODS.get(str(args.get("method", DEFAULT_METHOD)))
    return method.metric if method is not None else None


def workers_of(args: argparse.Namespace) -> Any:
    """The `Workers` the flags of `RayWorkers` ask for, or None to run in this process."""
    return requested_workers(args.workers, args.ray_address, args.cpus)


def _evaluation(result: Result) -> str:
    from imitation.evaluation.task_measures import measures_line

    evaluation = result["eval"]
    measured = measures_line(evaluation)
    return f"eval return {evaluation['mean_return']:.1f} ± {evaluation['std_return']:.1f}" + (
        f" ({measured})" if measured else ""
    )


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
        workers=workers_of(args),
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
        workers=workers_of(args),
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
        workers=workers_of(args),
        warm_start=args.warm_start,
    )


def _train_irl(args: argparse.Namespace) -> Trained:
    run = _irl_run(args)
    method = IRL_METHODS[args.method]
    result = method.train(run)
    return Trained(result, lambda: [method.describe(run, result)])


def _irl_options() -> tuple[Options, ...]:
    """`train irl`'s flags: --method and the commands' own, then each method's configs, the
    help of a flag shared by several methods saying what it does in each."""
    methods: dict[tuple[type, tuple[str, ...] | None], list[str]] = {}
    default_texts: dict[tuple[type, tuple[str, ...] | None], dict[str, str]] = {}
    for method in IRL_METHODS.values():
        for source in method.configs:
            methods.setdefault(source, []).append(method.name)
            default_texts.setdefault(source, {}).update(method.flag_defaults)
    configs = tuple(
        settings(config, only=only, label="/".join(names), default_texts=default_texts[config, only])
        for (config, only), names in methods.items()
    )
    return (
        Options(IRLOptions, choices={"method": tuple(IRL_METHODS)}),
        *configs,
        Options(RayWorkers, helps=workers_helps("PPO's rollouts (gcl, airl, gail)")),
        TRAIN_OUTPUT,
    )


TRAIN_OUTPUT = Options(RunOutput)
SEARCH_DESCRIPTION = (
    " Candidates act deterministically (the mode of π_θ); each is scored by its mean return over the same "
    "--episodes-per-candidate episodes, run side by side in --n-envs env copies. The budget is env steps: no generation "
    "starts that could pass it. `eval policy RUN_DIR` evaluates the result."
)


register(
    TrainLearner(
        "ppo",
        Command(
            "the bundled PPO trainer (clip or adaptive-KL objective, GAE)",
            "Train PPO on a gymnasium env, on its own reward or on a learned one (--reward). Per-environment defaults "
            "(rl-baselines3-zoo's settings where known; its Atari settings for image observations) make flags optional. A "
            "reward learnt on pixels brings its --pixels, --grayscale, --crop and --frame-stack.",
            (
                settings(PPOConfig),
                Options(PPOOptions),
                Options(Pixels, helps=pixels_helps("the policy sees (through a CNN) are")),
                Options(RayWorkers, helps=workers_helps("the rollouts (the environment copies split between them)")),
                TRAIN_OUTPUT,
            ),
        ),
        _train_ppo,
    )
)
register(
    TrainLearner(
        "pg",
        Command(
            "policy gradient: REINFORCE (whole return, reward-to-go, baseline) or actor-critic",
            "Policy gradient from first principles: each batch of complete episodes gives one gradient step on "
            "(1/m) Σ_i Σ_t ∇log π(a_t|s_t) w_t, w_t the trajectory's return, the reward-to-go, the reward-to-go minus a "
            "learned V(s_t), or an actor-critic advantage (n-step with --n-step, else GAE(λ)). Softmax policies for discrete "
            "actions, Gaussian for continuous ones. Per-environment defaults make the other flags optional.",
            (settings(PGConfig), TRAIN_OUTPUT),
        ),
        _train_pg,
    )
)
register(
    TrainLearner(
        "hill-climb",
        Command(
            "gradient-free: hill climbing with adaptive noise over the policy's parameters",
            "Hill climbing: each generation perturbs the incumbent θ by σε for --population candidates and keeps the best if "
            "it beats θ, re-evaluated on the same episodes; σ halves after an improvement and doubles otherwise. The run "
            "keeps the incumbent." + SEARCH_DESCRIPTION,
            (settings(SearchConfig), TRAIN_OUTPUT),
        ),
        _train_search,
    )
)
register(
    TrainLearner(
        "cem",
        Command(
            "gradient-free: the cross-entropy method over the policy's parameters",
            "The cross-entropy method: each generation samples --population parameter vectors from N(μ, diag σ²) and refits "
            "μ and σ² to the --elite-fraction best, plus a decreasing extra variance. The run keeps the mean μ."
            + SEARCH_DESCRIPTION,
            (settings(SearchConfig), TRAIN_OUTPUT),
        ),
        _train_search,
    )
)
register(
    TrainLearner(
        "cmaes",
        Command(
            "gradient-free: CMA-ES (the cma library) over the policy's parameters",
            "CMA-ES by the cma library (ask/tell): full covariance and global step size. The run keeps the mean."
            + SEARCH_DESCRIPTION,
            (settings(SearchConfig), TRAIN_OUTPUT),
        ),
        _train_search,
    )
)
register(
    TrainLearner(
        "bc",
        Command(
            "behavioural cloning on MCAP demos",
            "Behavioural cloning: fit a policy to the demos' (observation, action) pairs. Whole episodes are held out for "
            "validation (offline, a single recording holds out the last steps of each episode instead); training stops early "
            "when the validation loss stops improving.",
            (Options(BCOptions), settings(BCConfig), TRAIN_OUTPUT),
        ),
        _train_bc,
        metric=("validation_loss", "min", "best"),
    )
)
register(
    TrainLearner(
        "dagger",
        Command(
            "DAgger: BC on expert-labelled states the learner itself visits",
            "DAgger: each round rolls out a β-mixture of expert and learner, labels every visited state with the expert's "
            "action, writes the round as RUN_DIR/rounds/round-NN.mcap and retrains BC on everything so far. With --mode "
            "takeover (HG-DAgger) the learner drives until the expert takes the controls, and BC learns from the steps the "
            "expert drove. Each round file records who drove every step, the learner's proposed and the executed action "
            "(/intervention channels; `imitation info RUN_DIR` shows the rate by round). A person as the expert (keyboard, "
            "gamepad) sees a window: P pauses, - and = halve and double the speed, Esc stops (the round's finished episodes "
            "are kept; --resume continues the round).",
            (
                Options(DAggerOptions),
                Options(PersonSpeed),
                Options(Pixels, helps=pixels_helps("the learner sees")),
                settings(DAggerConfig),
                Options(
                    RayWorkers, helps=workers_helps("each round's episodes, each worker writing its own shard of the round")
                ),
                TRAIN_OUTPUT,
            ),
        ),
        _train_dagger,
    )
)
register(
    TrainLearner(
        "irl",
        Command(
            "IRL: recover a reward from demos (tabular maxent/mce, continuous gcl, airl, gail, apprenticeship)",
            "Maximum-entropy inverse RL. maxent (Ziebart 2008, deterministic dynamics) and mce (maximum causal entropy, "
            "any dynamics) need a tabular env with known dynamics (imitation/GridWorld8x8-v0, ...); gcl (guided cost "
            "learning) works on continuous envs and trains PPO on the reward as it learns it; so do the adversarial "
            "methods, airl (Fu et al. 2018: a discriminator structured by the policy's density and a shaping potential, "
            "whose state-only reward g is recovered) and gail (Ho & Ermon 2016: a free discriminator, PPO on −log(1 − D); "
            "its policy is the product, its discriminator a reward only with that caveat). apprenticeship (Abbeel & Ng "
            "2004, projection method) matches the demos' feature expectations with a mixture of policies: exactly on a "
            "tabular env, with PPO as the solver on Box observations. The run directory holds the reward model, for "
            "`train ppo --reward RUN_DIR`.",
            _irl_options,
        ),
        _train_irl,
        metric=None,
    )
)
