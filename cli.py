"""The `imitation` command line: parse, call one library function, print.

Errors are one line on stderr with exit code 1 (2 for usage errors); `--json` prints exactly one
JSON object on stdout as the last line. Heavy libraries (torch, lerobot) are imported only by
the commands that need them, so `imitation --help` and `imitation info` start fast.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import threading
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from imitation import __version__, flags
from imitation.errors import ConfigError, ImitationError
from imitation.flags import add_flags, given

EXIT_ERROR = 1
EXIT_INTERRUPTED = 130
MAX_ERROR_CHARS = 2000


def _print_json(data: dict[str, Any] | list[dict[str, Any]]) -> None:
    print(json.dumps(data, sort_keys=False))


def cmd_record(args: argparse.Namespace) -> int:
    from imitation.envs.pixels import PixelRecipe
    from imitation.jobs.record import record_job
    from imitation.jobs.record_config import RecordConfig

    result = record_job(
        RecordConfig(**given(args, RecordConfig)),
        args.out,
        pixels=PixelRecipe.parse(args.pixels, grayscale=args.grayscale, crop=args.crop) if args.pixels else None,
        speed=args.speed,
        progress=not args.quiet,
    )
    if args.json:
        _print_json(result)
    else:
        print(
            f"recorded {result['episodes']} episodes of {args.env} to {args.out}: mean return {result['mean_return']:.2f} "
            f"(min {result['min_return']:.2f}, max {result['max_return']:.2f})"
        )
    return 0


def cmd_info(args: argparse.Namespace) -> int:
    from imitation.data.summary import format_rounds, format_summary, round_files, summarize

    if os.path.isdir(args.file):
        rounds = round_files(args.file)
        if not rounds:
            raise ImitationError(
                f"{args.file}: a directory without rounds/round-NN.mcap files (a DAgger run); give a demo file"
            )
        summaries = [summarize(path) for path in rounds]
        if args.json:
            _print_json(summaries)
        else:
            print(format_rounds(summaries))
        return EXIT_ERROR if any(summary["damage"] for summary in summaries) else 0
    summary = summarize(args.file)
    if args.json:
        _print_json(summary)
    else:
        print(format_summary(summary))
    if summary["damage"]:
        print(
            f"error: {summary['file']}: damaged ({summary['damage']}); {summary['salvaged']} complete episodes are readable",
            file=sys.stderr,
        )
        return EXIT_ERROR
    return 0


def cmd_recover(args: argparse.Namespace) -> int:
    from imitation.data.recover import recover_partial

    result = recover_partial(args.partial, args.out, compression=args.compression)
    if args.json:
        _print_json(result)
        return 0
    print(
        f"recovered {result['episodes']} complete episodes ({result['transitions']} transitions) from {result['partial']} to "
        f"{result['out']}"
    )
    if result["lost"]:
        print(f"not recovered: {result['lost']}")
    print(
        f"removed {result['partial']}"
        if result["partial_removed"]
        else f"kept {result['partial']}: the damage is not only an unfinished tail"
    )
    return 0


def _print_warnings(warnings: list[str]) -> None:
    for warning in warnings:
        print(f"warning: {warning}", file=sys.stderr)


def cmd_convert(args: argparse.Namespace) -> int:
    from imitation.data.convert.job import convert, inspect

    if args.inspect or args.write_map:
        if args.out or args.map or args.env or args.layout:
            args.parser.error("--inspect lists a bag's topics; it takes no --out, --map, --layout or --env")
        report = inspect(args.source, source=args.source_kind, write_map=args.write_map, ros_distro=args.ros_distro)
        _print_warnings(report["warnings"])
        if args.json:
            _print_json(report)
        else:
            from imitation.data.convert.inspect import format_report

            print(format_report(report))
            if report["map"]:
                print(
                    f"wrote a starter map to {report['map']}; edit it, then: imitation convert {args.source} --map "
                    f"{report['map']} --out demos.mcap"
                )
        return 0
    if not args.out:
        args.parser.error("--out F.mcap is required (or --inspect to list a bag's topics)")
    from imitation.data.image_resize import parse_image_size

    result = convert(
        args.source,
        args.out,
        source=args.source_kind,
        map_path=args.map,
        layout_path=args.layout,
        env_id=args.env,
        ros_distro=args.ros_distro,
        progress=not args.quiet,
        image_codec=args.image_codec,
        image_quality=args.image_quality,
        image_size=parse_image_size(args.image_size, "--image-size") if args.image_size is not None else None,
        video_tolerance_s=args.video_tolerance,
    )
    _print_warnings(result["warnings"])
    if args.json:
        _print_json(result)
    else:
        print(
            f"converted {result['from']} {args.source} to {result['out']}: {result['episodes']} episodes, "
            f"{result['transitions']} transitions; observation {result['observation_space']}, action "
            f"{result['action_space']}; env {result['env_id'] or '- (none: offline demos)'}"
        )
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    target, destination = args.to
    if target == "lerobot":
        from imitation.data.export.lerobot import export_lerobot

        result = export_lerobot(args.file, destination, progress=not args.quiet)
        summary = f"{result['episodes']} episodes, {result['frames']} frames at {result['fps']} fps (LeRobotDataset v3.0)"
    elif target == "foxglove":
        from imitation.data.export.foxglove import export_foxglove

        result = export_foxglove(args.file, destination, progress=not args.quiet)
        summary = f"{result['episodes']} episodes, {result['messages']} JSON messages on {', '.join(result['topics'])}"
    else:
        raise ImitationError(f"--to {target}: unknown format; use lerobot DIR or foxglove F2.mcap")
    if args.json:
        _print_json(result)
    else:
        print(f"exported {args.file} to {destination}: {summary}")
    return 0


def cmd_train_ppo(args: argparse.Namespace) -> int:
    from imitation.algorithms.ppo_config import PPOConfig
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
    if args.json:
        _print_json(result)
    else:
        evaluation = result["eval"]
        print(
            f"trained PPO ({config.objective}) on {args.env} for {result['steps']} steps in {result['seconds']:.0f} s "
            f"({result['steps_per_second']:.0f} steps/s); eval return {evaluation['mean_return']:.1f} ± "
            f"{evaluation['std_return']:.1f}; run: {result['run']}"
        )
    return 0


def cmd_train_pg(args: argparse.Namespace) -> int:
    from imitation.algorithms.policy_gradient_config import PGConfig
    from imitation.jobs.pg import pg_config, pg_job

    config = pg_config(**given(args, PGConfig))
    result = pg_job(config, args.out, progress=not args.quiet, resume=args.resume)
    if args.json:
        _print_json(result)
    else:
        evaluation = result["eval"]
        print(
            f"trained policy gradient ({config.estimator}) on {args.env} for {result['steps']} steps in "
            f"{result['batches']} batches, {result['seconds']:.0f} s; eval return {evaluation['mean_return']:.1f} ± "
            f"{evaluation['std_return']:.1f}; run: {result['run']}"
        )
    return 0


def cmd_train_search(args: argparse.Namespace) -> int:
    from imitation.algorithms.policy_search_config import SearchConfig
    from imitation.jobs.search import search_config, search_job

    config = search_config(method=args.algorithm, **given(args, SearchConfig))
    result = search_job(config, args.out, progress=not args.quiet, resume=args.resume)
    if args.json:
        _print_json(result)
    else:
        evaluation = result["eval"]
        print(
            f"searched {result['parameters']} policy parameters by {args.algorithm} on {args.env}: {result['steps']} steps, "
            f"{result['generations']} generations in {result['seconds']:.0f} s; eval return of the "
            f"{'incumbent' if args.algorithm == 'hill-climb' else 'mean'} {evaluation['mean_return']:.1f} ± "
            f"{evaluation['std_return']:.1f}; run: {result['run']}"
        )
    return 0


def cmd_train_bc(args: argparse.Namespace) -> int:
    from imitation.algorithms.bc_config import BCConfig
    from imitation.jobs.bc import bc_job

    result = bc_job(
        args.demos, args.env, BCConfig(**given(args, BCConfig)), args.out, progress=not args.quiet, resume=args.resume
    )
    if "run" not in result:  # a torchrun process other than rank 0, which reports the run
        return 0
    _print_warnings(result["warnings"])
    if args.json:
        _print_json(result)
        return 0
    if result["offline"]:
        print(
            f"trained BC offline (no --env, so no rollouts) on {result['train_transitions']} transitions for "
            f"{result['epochs']} epochs (best {result['best_epoch']}); validation loss {result['best_validation_loss']:.4f} "
            f"on {result['validation_transitions']} held-out transitions; run: {result['run']}"
        )
    else:
        evaluation = result["eval"]
        print(
            f"trained BC on {result['train_transitions']} transitions for {result['epochs']} epochs (best "
            f"{result['best_epoch']}, validation loss {result['best_validation_loss']:.4f}); eval return "
            f"{evaluation['mean_return']:.1f} ± {evaluation['std_return']:.1f}; run: {result['run']}"
        )
    if result["validation"] is not None:
        print(_yardstick_line(result["validation"], result["baselines"], result["beats_baselines"]))
    return 0


def _yardstick_line(scores: dict[str, float], baselines: dict[str, dict[str, float]], beats: dict[str, bool]) -> str:
    """BC beside the trivial baselines, on the held-out transitions, in one line."""

    def shown(values: dict[str, float]) -> str:
        return ", ".join(f"{key.replace('_', ' ')} {value:.4g}" for key, value in values.items())

    rows = "; ".join(
        f"{name.replace('_', '-')} {shown(values)} ({'beaten' if beats[name] else 'NOT beaten'})"
        for name, values in baselines.items()
    )
    return f"held-out: BC {shown(scores)}; baselines: {rows}"


def cmd_train_dagger(args: argparse.Namespace) -> int:
    from imitation.algorithms.dagger_config import DAggerConfig
    from imitation.jobs.dagger import dagger_job

    config = DAggerConfig(**given(args, DAggerConfig))
    from imitation.envs.pixels import PixelRecipe

    pixels = PixelRecipe.parse(args.pixels, grayscale=args.grayscale, crop=args.crop) if args.pixels else None
    result = dagger_job(
        args.env,
        args.expert,
        config,
        args.out,
        demos=args.demos,
        pixels=pixels,
        speed=args.speed,
        progress=not args.quiet,
        resume=args.resume,
        workers=_workers(args),
    )
    if args.json:
        _print_json(result)
    else:
        evaluation = result["eval"]
        returns = ", ".join(f"{value:.1f}" for value in result["round_returns"])
        print(
            f"DAgger on {args.env} with expert {args.expert}: {result['rounds']} rounds, {result['expert_labels']} expert "
            f"labels; return by round: {returns}; eval return {evaluation['mean_return']:.1f} ± "
            f"{evaluation['std_return']:.1f}; run: {result['run']}"
        )
        if config.mode == "takeover":
            rates = ", ".join(f"{100 * rate:.1f} %" for rate in result["intervention_rates"])
            print(f"intervention rate by round (share of steps the expert drove): {rates}")
    return 0


def cmd_train_irl(args: argparse.Namespace) -> int:
    if args.workers is not None and args.method not in ("gcl", "gail", "airl"):
        raise ImitationError(f"--workers: --method {args.method} has no PPO rollouts to spread; use it with gcl, airl or gail")
    if args.gail_reward is not None and args.method != "gail":
        raise ImitationError(f"--gail-reward: chooses GAIL's reward, and --method {args.method} is not gail")
    from imitation.algorithms.adversarial_config import DISCRIMINATOR_TRAINING, AdversarialConfig

    for name in given(args, AdversarialConfig, only=DISCRIMINATOR_TRAINING):
        if args.method not in ("gail", "airl"):
            raise ImitationError(
                f"{flags.flag_of(args.configs, 'AdversarialConfig', name)}: sets the training of GAIL's and AIRL's "
                f"discriminator, and --method {args.method} has none"
            )
    if args.warm_start is not None and args.method not in ("gail", "airl"):
        raise ImitationError(f"--warm-start: starts GAIL's and AIRL's discriminator, and --method {args.method} has none")
    if args.method == "gcl":
        return _train_gcl(args)
    if args.method in ("gail", "airl"):
        return _train_adversarial(args)
    if args.method == "apprenticeship":
        return _train_apprenticeship(args)
    from imitation.algorithms.maxent_irl_config import MaxEntIRLConfig
    from imitation.jobs.irl import tabular_irl_job

    config = MaxEntIRLConfig(method=args.method, **given(args, MaxEntIRLConfig))
    result = tabular_irl_job(args.demos, args.env, config, args.out, progress=not args.quiet, resume=args.resume)
    if args.json:
        _print_json(result)
    else:
        print(
            f"{args.method} IRL on {args.env}: {result['iterations']} iterations, occupancy error "
            f"{result['occupancy_error']:.2e}; the soft-optimal policy for the learned reward earns "
            f"{result['learned_policy_return']:.2f} (expert {result['expert_return']:.2f}, random "
            f"{result['random_return']:.2f}, normalised {result['normalized_return']:.3f}); run: {result['run']}"
        )
    return 0


def _ppo_beside_irl(args: argparse.Namespace) -> Any:
    """The PPOConfig of `train irl --method gcl|gail|airl`: the env's preset for a policy beside a
    reward being learnt, its IRL length, the flags, and the frames the demos were recorded with."""
    from imitation.algorithms.ppo_config import PPOConfig
    from imitation.jobs.irl import recorded_observation
    from imitation.jobs.presets import ppo_config, preset

    flagged = given(args, PPOConfig, only=("total_steps", "seed"))
    fields = {"total_steps": preset(args.env).irl_steps} | flagged | recorded_observation(args.demos)
    return ppo_config(args.env, beside_irl=True, **fields)


def _train_gcl(args: argparse.Namespace) -> int:
    from imitation.algorithms.gcl_config import GCLConfig
    from imitation.jobs.irl import gcl_job

    result = gcl_job(
        args.demos,
        args.env,
        GCLConfig(**given(args, GCLConfig)),
        _ppo_beside_irl(args),
        args.out,
        progress=not args.quiet,
        resume=args.resume,
        workers=_workers(args),
    )
    if args.json:
        _print_json(result)
    else:
        evaluation = result["eval"]
        print(
            f"GCL on {args.env}: {result['steps']} PPO steps in {result['seconds']:.0f} s; the maximum-entropy sampler "
            f"trained alongside (not for use) earns {evaluation['mean_return']:.1f} ± {evaluation['std_return']:.1f} (demos "
            f"{result['demo_return']:.1f}); reward model for `train ppo --reward`: {result['run']}"
        )
    return 0


def _train_adversarial(args: argparse.Namespace) -> int:
    from imitation.algorithms.adversarial_config import AdversarialConfig
    from imitation.jobs.irl import adversarial_job

    result = adversarial_job(
        args.demos,
        args.env,
        AdversarialConfig(method=args.method, **given(args, AdversarialConfig)),
        _ppo_beside_irl(args),
        args.out,
        progress=not args.quiet,
        resume=args.resume,
        workers=_workers(args),
        warm_start=args.warm_start,
    )
    if args.json:
        _print_json(result)
    else:
        evaluation = result["eval"]
        reward = "g" if args.method == "airl" else "−log(1 − D), not a recovered reward"
        print(
            f"{args.method.upper()} on {args.env}: {result['steps']} PPO steps in {result['seconds']:.0f} s; the policy "
            f"earns {evaluation['mean_return']:.1f} ± {evaluation['std_return']:.1f} (demos {result['demo_return']:.1f}), "
            f"discriminator accuracy {result['demo_accuracy']:.2f} on demos, {result['sample_accuracy']:.2f} on samples; "
            f"policy for `eval policy` and reward ({reward}) for `train ppo --reward`: {result['run']}"
        )
    return 0


def _train_apprenticeship(args: argparse.Namespace) -> int:
    from imitation.algorithms.apprenticeship_config import ApprenticeshipConfig
    from imitation.jobs.apprenticeship import apprenticeship_job
    from imitation.jobs.presets import ppo_config

    config = ApprenticeshipConfig(**given(args, ApprenticeshipConfig))
    # The PPO solver's steps per iteration are ApprenticeshipConfig's, so --steps is not PPOConfig's here.
    solver = ppo_config(args.env, learned_reward=True, seed=config.seed, total_steps=config.solver_steps)
    result = apprenticeship_job(args.demos, args.env, config, solver, args.out, progress=not args.quiet, resume=args.resume)
    if args.json:
        _print_json(result)
        return 0
    mixture = result["mixture"]
    print(
        f"apprenticeship learning on {args.env}: {result['iterations']} iterations, ‖μ_E - μ̄‖/‖μ_E‖ = "
        f"{result['relative_feature_distance']:.4f}; the mixture of {len(mixture['lambdas'])} policies earns "
        f"{mixture['return']:.2f} (normalised {mixture['normalized_return']:.3f}); reward and policy (member "
        f"{result['chosen_member']}) in: {result['run']}"
    )
    return 0


def cmd_eval_policy(args: argparse.Namespace) -> int:
    from imitation.jobs.evaluate_policy import eval_policy_job
    from imitation.jobs.evaluate_policy_config import PolicyEvaluationConfig

    settings = PolicyEvaluationConfig(**given(args, PolicyEvaluationConfig))
    result = eval_policy_job(args.run, args.env, settings)
    if args.json:
        _print_json(result)
        return 0
    print(
        f"{args.run} on {args.env}: mean return {result['mean_return']:.2f} ± {result['std_return']:.2f} "
        f"(min {result['min_return']:.2f}, max {result['max_return']:.2f}) over {settings.episodes} episodes"
    )
    if "normalized_return" in result:
        reference = result["reference"]
        print(
            f"normalised return {result['normalized_return']:.3f} (0 = {reference['random_return']:.2f}, 1 = "
            f"{reference['expert_return']:.2f}: {reference['source']})"
        )
    if args.video:
        print(f"video of episode 0 (return {result['video']['return']:.2f}): {args.video}")
    return 0


def cmd_eval_reward(args: argparse.Namespace) -> int:
    import torch

    from imitation.jobs.evaluate_reward import evaluate_reward
    from imitation.jobs.evaluate_reward_config import RewardEvaluationConfig

    torch.set_num_threads(1)  # EPIC's many small reward calls: faster on one thread (bench/RESULTS.md)
    config = RewardEvaluationConfig(**given(args, RewardEvaluationConfig))
    out = args.out or str(Path(args.run) / "eval-reward")
    result = evaluate_reward(args.run, args.env, config, out, progress=not args.quiet, workers=_workers(args))
    if args.json:
        _print_json(result)
        return 0
    print(f"{args.run} on {args.env}:")
    retrain = result["retrain"]
    rows = [("recovered", result["epic"], result["pearson"], retrain["normalized"])]
    rows += [(name, c["epic"], c["pearson"], c["normalized"]) for name, c in result["controls"].items()]
    for name, epic, pearson, score in rows:

        def shown(value: float | None) -> str:
            return "n/a" if value is None else f"{value:.3f}"

        print(f"  {name:>9} reward: EPIC {shown(epic)}, Pearson {shown(pearson)}, retrained normalised return {shown(score)}")
    if result.get("coverage", {}).get("true_reward", "").startswith("constant"):
        print(f"  note: the true reward is {result['coverage']['true_reward']}")
    print(f"report: {Path(result['out']) / 'report.md'}")
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    from imitation.jobs.demo import run_demo

    result = run_demo(
        args.out, quick=args.quick, progress=not args.quiet, **({"datasets": args.datasets} if args.datasets else {})
    )
    if args.json:
        _print_json(result)
    else:
        print(f"demo finished in {result['seconds']:.0f} s; report: {result['report']}")
    return 0


def cmd_sweep(args: argparse.Namespace) -> int:
    from imitation.jobs.sweep import sweep_job
    from imitation.jobs.sweep_config import CommandLine, read_sweep_config

    config = read_sweep_config(args.config, CommandLine(commands=_train_commands(), problem=_train_problem))
    if args.cpus is not None and args.cpus < 1:
        raise ImitationError(f"--cpus must be at least 1, got {args.cpus}")
    out = args.out or str(Path("sweeps") / Path(args.config).stem)
    # The trials' runner by its module's name, which Tune's process and Ray's workers import: run
    # as `python cli.py`, this file is __main__, a name no other process can import.
    import cli

    result = sweep_job(config, out, cli._run_train, ray_address=args.ray_address, cpus=args.cpus)
    if args.json:
        _print_json({key: value for key, value in result.items() if key != "table"})
        return 0
    print(result["table"])
    best = result["best"]
    print(
        f"swept {result['trials']} trials in {result['seconds']:.0f} s: {result['finished']} finished, "
        f"{result['stopped_early']} stopped early, {result['failed']} failed; "
        + (f"best {best['trial']} ({config.metric} {best[config.metric]:.4g}): {best['run']}" if best else "no trial finished")
    )
    return 0


def _subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    return next(action.choices for action in parser._actions if isinstance(action, argparse._SubParsersAction))


def _train_commands() -> dict[str, frozenset[str]]:
    """Each `train` command with its flags, without dashes: what a sweep config may set."""
    return {
        f"train {name}": frozenset(
            option[2:] for action in parser._actions for option in action.option_strings if option[:2] == "--"
        )
        for name, parser in _subcommands(_subcommands(build_parser())["train"]).items()
    }


def _train_problem(argv: list[str]) -> str | None:
    """argparse's one-line objection to the command line `argv`, or None when it parses."""
    import contextlib
    import io

    stderr = io.StringIO()
    try:
        with contextlib.redirect_stderr(stderr):
            build_parser().parse_args(argv)
    except SystemExit:
        lines = stderr.getvalue().strip().splitlines()
        return lines[-1].split(": error: ", 1)[-1] if lines else "not a command line of imitation"
    return None


def _run_train(argv: list[str]) -> None:
    """Run the `train` command line `argv` in this process, as a sweep's trial does: a failure is
    raised as one line in the command line's words, not printed."""
    args = build_parser().parse_args(argv)
    args.command_key = f"{args.command} {args.algorithm}"
    _apply_limits([])  # the sweep's --limit reached this worker through IMITATION_LIMITS
    try:
        args.handler(args)
    except ConfigError as error:
        raise ImitationError(_flag_message(error, args)) from None


def _add_pixel_arguments(parser: argparse.ArgumentParser, what: str) -> None:
    parser.add_argument(
        "--pixels",
        metavar="HxW",
        help=f"observations {what} rendered frames resized to H×W (e.g. 84x84) under the key 'pixels', with the env's own "
        "observation beside them as 'state' (the expert acts on the state)",
    )
    parser.add_argument("--grayscale", action="store_true", help="with --pixels: one luma channel instead of RGB")
    parser.add_argument(
        "--crop",
        metavar="T,L,H,W",
        help="with --pixels: keep only this rectangle of the rendered image (top, left, height, width in pixels) "
        "before resizing, e.g. 150,200,180,200 around CartPole's cart and pole in its 400×600 frame",
    )


def _flag_message(error: ConfigError, args: argparse.Namespace) -> str:
    """A config error in the command line's words: the field named by the flag that sets it, a
    config flag or the command's own option of the field's name (`train irl --method`)."""
    flag = flags.flag_of(getattr(args, flags.SOURCES, ()), error.owner, error.field)
    if flag is None and error.field in vars(args):
        flag = "--" + error.field.replace("_", "-")
    return error.renamed(flag) if flag is not None else str(error)


def _add_speed(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--speed",
        type=flags.speed,
        default=1.0,
        metavar="X",
        help="with --expert keyboard or gamepad: the window runs at X times real time, from 0.125 to 4 (default: 1)",
    )


def _add_workers(parser: argparse.ArgumentParser, what: str) -> None:
    """--workers, --ray-address and --cpus: `what` runs on Ray (the optional extra `ray`)."""
    parser.add_argument(
        "--workers",
        type=int,
        metavar="N",
        help=f"run {what} on N Ray workers (pip install 'imitation-mcap[ray]'; default: in this process, no Ray)",
    )
    parser.add_argument(
        "--ray-address",
        default="local",
        metavar="ADDR|auto|local",
        help="with --workers: the Ray cluster to use; 'local' starts one on this machine for the run (default: local)",
    )
    parser.add_argument(
        "--cpus", type=int, metavar="C", help="with --workers and a local Ray: the CPUs it may use (default: every core)"
    )


def _workers(args: argparse.Namespace) -> Any:
    """The `Workers` the flags of `_add_workers` ask for, or None to run in this process."""
    from imitation.ray_engine import LOCAL, Workers

    if args.workers is None:
        if args.ray_address != LOCAL or args.cpus is not None:
            raise ImitationError("--ray-address and --cpus go with --workers N")
        return None
    return Workers(args.workers, args.ray_address, args.cpus)


def _add_resume(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--resume",
        action="store_true",
        help="continue the interrupted run in RUN_DIR.partial from its last checkpoint (saved every tenth of the run, after "
        "its last step and on Ctrl-C), with the same settings, to the same total",
    )


def _add_run_output(parser: argparse.ArgumentParser) -> None:
    """--out, --json and --quiet, shared by every `train` command."""
    parser.add_argument(
        "--out", required=True, metavar="RUN_DIR", help="run directory to write (replaced only when the run completes)"
    )
    parser.add_argument("--json", action="store_true", help="print one JSON object with the results")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def _add_search_parsers(algorithms: Any) -> None:
    """`train hill-climb`, `train cem`, `train cmaes`: one command per gradient-free search, same flags."""
    from imitation.algorithms.policy_search_config import SearchConfig

    searches = {
        "hill-climb": (
            "gradient-free: hill climbing with adaptive noise over the policy's parameters",
            "Hill climbing: each generation perturbs the incumbent θ by σε for --population candidates and keeps the "
            "best if it beats θ, re-evaluated on the same episodes; σ halves after an improvement and doubles "
            "otherwise. The run keeps the incumbent.",
        ),
        "cem": (
            "gradient-free: the cross-entropy method over the policy's parameters",
            "The cross-entropy method: each generation samples --population parameter vectors from N(μ, diag σ²) and "
            "refits μ and σ² to the --elite-fraction best, plus a decreasing extra variance. The run keeps the mean μ.",
        ),
        "cmaes": (
            "gradient-free: CMA-ES (the cma library) over the policy's parameters",
            "CMA-ES by the cma library (ask/tell): full covariance and global step size. The run keeps the mean.",
        ),
    }
    for method, (summary, description) in searches.items():
        search = algorithms.add_parser(
            method,
            help=summary,
            description=description + " Candidates act deterministically (the mode of π_θ); each is scored by its "
            "mean return over the same --episodes-per-candidate episodes, run side by side in --n-envs env copies. "
            "The budget is env steps: no generation starts that could pass it. `eval policy RUN_DIR` evaluates the "
            "result.",
        )
        add_flags(search, SearchConfig)
        _add_run_output(search)
        _add_resume(search)
        search.set_defaults(handler=cmd_train_search)


def build_parser() -> argparse.ArgumentParser:
    from imitation.algorithms.adversarial_config import AdversarialConfig
    from imitation.algorithms.apprenticeship_config import ApprenticeshipConfig
    from imitation.algorithms.bc_config import BCConfig
    from imitation.algorithms.dagger_config import DAggerConfig
    from imitation.algorithms.gcl_config import GCLConfig
    from imitation.algorithms.maxent_irl_config import MaxEntIRLConfig
    from imitation.algorithms.policy_gradient_config import PGConfig
    from imitation.algorithms.ppo_config import PPOConfig
    from imitation.jobs.evaluate_policy_config import PolicyEvaluationConfig
    from imitation.jobs.evaluate_reward_config import RewardEvaluationConfig
    from imitation.jobs.record_config import RecordConfig

    parser = argparse.ArgumentParser(
        prog="imitation",
        description="Imitation learning on MCAP demonstration files: record, inspect, train, evaluate.",
    )
    parser.add_argument("--version", action="version", version=f"imitation-mcap {__version__}")
    parser.add_argument(
        "--limit",
        action="append",
        default=[],
        metavar="NAME=N",
        help="raise a resource bound for this run, e.g. --limit sample_elements=33554432 (bounds: sample_elements, "
        "dict_leaves, expansion_ratio, chunk_bytes, yaml_nodes, policy_parameters, grid_steps_per_message, "
        "remote_stall_seconds, remote_request_seconds, remote_total_seconds, remote_request_bytes; see imitation/limits.py)",
    )
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    record = commands.add_parser(
        "record",
        help="record expert episodes of a gymnasium env into an MCAP demo file",
        description="Run an expert in a gymnasium environment and write each finished episode to an MCAP "
        "demo file as it ends (while recording the file is named F.mcap.partial; Ctrl-C keeps the finished episodes).",
    )
    add_flags(record, RecordConfig)
    record.add_argument("--out", required=True, metavar="F.mcap", help="output demo file")
    _add_pixel_arguments(record, "recorded as")
    _add_speed(record)
    record.add_argument("--json", action="store_true", help="print one JSON object with the results")
    record.add_argument("--quiet", action="store_true", help="no progress bar")
    record.set_defaults(handler=cmd_record)

    info = commands.add_parser(
        "info",
        help="describe a demo file: episodes, returns, lengths, spaces, channels, damage",
        description="Describe an MCAP demo file, or each round of a DAgger run directory, with how much a person "
        "drove (the intervention rate) where the file records it. Every chunk is checked; a damaged file is described by the "
        "complete episodes that can be salvaged and the command exits with code 1.",
    )
    info.add_argument("file", metavar="F.mcap", help="demo file, or a DAgger run directory: one line per round")
    info.add_argument("--json", action="store_true", help="print one JSON object")
    info.set_defaults(handler=cmd_info)

    recover = commands.add_parser(
        "recover",
        help="turn the F.mcap.partial of an interrupted or failed write into a demo file",
        description="A writer that was killed, ran out of disk space or stopped on an error leaves F.mcap.partial with "
        "every episode it had finished. recover writes those episodes, bit-exact, to a new demo file (default: F.mcap), "
        "then removes the partial file unless more than its unfinished tail was damaged.",
    )
    recover.add_argument("partial", metavar="F.mcap.partial", help="the partial demo file")
    recover.add_argument(
        "--out",
        metavar="F.mcap",
        help="the recovered file, which must not exist (default: the partial file's name without .partial)",
    )
    recover.add_argument(
        "--compression", choices=["lz4", "zstd", "none"], default="lz4", help="chunk compression (default: lz4)"
    )
    recover.add_argument("--json", action="store_true", help="print one JSON object")
    recover.set_defaults(handler=cmd_recover)

    convert = commands.add_parser(
        "convert",
        help="convert a ROS bag, a LeRobot dataset or npz rollouts into an MCAP demo file",
        description="Convert recordings into an MCAP demo file. ROS bags (ROS 2 .mcap file or rosbag2 directory, ROS 1 .bag, "
        "rosbag2 sqlite directory) need a map (YAML: topics and fields for the observation and action, rate, alignment, "
        "episodes, what a laser's inf beams stand for; see docs/CONVERT.md); --inspect lists a bag's topics and numeric "
        "fields and --write-map writes a starter map. LeRobot datasets (v3.0, v2.1) and npz rollouts (stable-baselines "
        "GAIL, HumanCompatibleAI/imitation) convert "
        "without a map; a bare (episodes, steps, columns) array needs a layout (--layout). Cameras become image "
        "observations: LeRobot video and image features, and ROS image topics a map names with image:, stored as "
        "--image-codec says and resized once by --image-size (or a map entry's resize:). With --env, end "
        "flags that the source cannot tell apart (a time limit or a terminal state) are decided from the env's time "
        "limit, or, for a layout with ends: terminal_state, where the env's own termination rule first holds on the "
        "recorded states (the steps after it are cut).",
    )
    convert.add_argument(
        "source",
        metavar="SRC",
        help="a .mcap bag or rosbag2 folder, a ROS 1 .bag, a LeRobot dataset root, an .npz file, or a .npy array",
    )
    convert.add_argument(
        "--from",
        dest="source_kind",
        metavar="KIND",
        help="ros2, ros1, lerobot, npz or array (default: recognised from SRC)",
    )
    convert.add_argument(
        "--map", metavar="MAP.yaml", help="for bags: which topics and fields form the observation and the action"
    )
    convert.add_argument(
        "--layout",
        metavar="LAYOUT.yaml",
        help="for bare arrays (.npy, or an npz member) of shape (episodes, steps, columns): which columns are observation "
        "and action, what rows hold, the padding, the reward, how episodes end (see docs/CONVERT.md)",
    )
    convert.add_argument("--out", metavar="F.mcap", help="output demo file (written atomically)")
    convert.add_argument(
        "--env", metavar="ID", help="gymnasium id the demos belong to: its spaces are used (overrides the map's env_id)"
    )
    convert.add_argument(
        "--inspect", action="store_true", help="list a bag's topics, types, counts, rates and numeric fields; convert nothing"
    )
    convert.add_argument(
        "--write-map",
        metavar="MAP.yaml",
        help="with --inspect: also write a starter map to edit (it steps at the command's rate, leaves out observations "
        "slower than one value per 10 steps, and takes a laser's ranges with nonfinite: range_max)",
    )
    convert.add_argument(
        "--image-codec",
        choices=["png", "jpeg", "webp", "raw"],
        default="png",
        help="how camera frames are stored: png (lossless), jpeg (lossy, quality 95), webp (lossy, quality 85; colour "
        "frames only) or raw (lossless, chunk-compressed). Measured on LeRobot's AV1 videos of 224x224 cameras, the "
        "demo file takes 13.8 times the videos' bytes as png, 5.5 as jpeg, 1.7 as webp (45 dB PSNR). A bag's JPEG or "
        "PNG frames, and a LeRobot image feature's, are stored as they are when the codec is theirs and they are not "
        "resized; video frames are decoded and encoded again (default: png)",
    )
    convert.add_argument(
        "--image-quality",
        type=flags.quality,
        metavar="Q",
        help="quality of --image-codec jpeg or webp, 1 to 100 (default: 95 for jpeg, 85 for webp)",
    )
    convert.add_argument(
        "--image-size",
        metavar="HxW",
        help="resize every camera's frames to H×W (area averaging) as they convert, e.g. 96x96; a bag's map entry may "
        "give its own resize: [H, W]; the frames' own size is kept in the file's metadata (default: as recorded)",
    )
    convert.add_argument(
        "--video-tolerance",
        type=flags.seconds,
        metavar="S",
        help="LeRobot videos: find each row's frame by its timestamp, within S seconds (default: by timestamp within "
        "1e-4 s, lerobot's tolerance, or by frame_index where the timestamps stray further, as a wall clock's do)",
    )
    convert.add_argument(
        "--ros-distro",
        default="latest",
        metavar="NAME",
        help=(
            "message definitions for rosbag2 sqlite bags that carry none (recorded before Iron): foxy, humble, ... "
            "(default: latest)"
        ),
    )
    convert.add_argument("--json", action="store_true", help="print one JSON object with the results")
    convert.add_argument("--quiet", action="store_true", help="no progress bar")
    convert.set_defaults(handler=cmd_convert, parser=convert)

    export = commands.add_parser(
        "export",
        help="export a demo file as a LeRobotDataset v3.0 or a per-step MCAP Foxglove can plot",
        description="Export an MCAP demo file: `--to lerobot DIR` writes a LeRobotDataset (codebase v3.0) that "
        "lerobot's LeRobotDataset loads; `--to foxglove F2.mcap` writes one JSON message per step, with a JSON schema, "
        "for plotting in Foxglove.",
    )
    export.add_argument("file", metavar="F.mcap", help="demo file")
    export.add_argument("--to", nargs=2, required=True, metavar=("FORMAT", "DEST"), help="lerobot DIR, or foxglove F2.mcap")
    export.add_argument("--json", action="store_true", help="print one JSON object with the results")
    export.add_argument("--quiet", action="store_true", help="no progress bar")
    export.set_defaults(handler=cmd_export)

    train = commands.add_parser(
        "train", help="train a policy or reward model", description="Train a policy or reward model into a run directory."
    )
    algorithms = train.add_subparsers(dest="algorithm", required=True, metavar="ALGORITHM")
    ppo = algorithms.add_parser(
        "ppo",
        help="the bundled PPO trainer (clip or adaptive-KL objective, GAE)",
        description="Train PPO on a gymnasium env, on its own reward or on a learned one (--reward). "
        "Per-environment defaults (rl-baselines3-zoo's settings where known; its Atari settings for image observations) "
        "make flags optional. A reward learnt on pixels brings its --pixels, --grayscale, --crop and --frame-stack.",
    )
    add_flags(ppo, PPOConfig)
    ppo.add_argument(
        "--reward",
        metavar="RUN_DIR",
        help="optimise this reward model instead of the env's reward (true returns are still logged); a pixel reward's "
        "frames are rendered as it was learnt on them",
    )
    ppo.add_argument(
        "--shaped",
        action="store_true",
        help="with --reward of an AIRL run: optimise f = g + γh(s') − h(s), its reward g shaped by the potential h it "
        "learnt (the same optimal policies as g)",
    )
    _add_pixel_arguments(ppo, "the policy sees (through a CNN) are")
    _add_workers(ppo, "the rollouts (the environment copies split between them)")
    _add_run_output(ppo)
    _add_resume(ppo)
    ppo.set_defaults(handler=cmd_train_ppo)

    pg = algorithms.add_parser(
        "pg",
        help="policy gradient: REINFORCE (whole return, reward-to-go, baseline) or actor-critic",
        description="Policy gradient from first principles: each batch of complete episodes gives one gradient step "
        "on (1/m) Σ_i Σ_t ∇log π(a_t|s_t) w_t, w_t the trajectory's return, the reward-to-go, the reward-to-go minus a "
        "learned V(s_t), or an actor-critic advantage (n-step with --n-step, else GAE(λ)). Softmax policies for "
        "discrete actions, Gaussian for continuous ones. Per-environment defaults make the other flags optional.",
    )
    add_flags(pg, PGConfig)
    _add_run_output(pg)
    _add_resume(pg)
    pg.set_defaults(handler=cmd_train_pg)

    _add_search_parsers(algorithms)

    bc = algorithms.add_parser(
        "bc",
        help="behavioural cloning on MCAP demos",
        description="Behavioural cloning: fit a policy to the demos' (observation, action) pairs. Whole episodes are "
        "held out for validation (offline, a single recording holds out the last steps of each episode instead); "
        "training stops early when the validation loss stops improving.",
    )
    bc.add_argument("--demos", required=True, nargs="+", metavar="F.mcap", help="one or more demo files of the same env")
    bc.add_argument(
        "--env",
        metavar="ID",
        help="gymnasium environment id (for spaces and evaluation); without it BC trains "
        "offline on the demos' own spaces and reports the validation loss only",
    )
    add_flags(bc, BCConfig)
    _add_run_output(bc)
    _add_resume(bc)
    bc.set_defaults(handler=cmd_train_bc)

    dagger = algorithms.add_parser(
        "dagger",
        help="DAgger: BC on expert-labelled states the learner itself visits",
        description="DAgger: each round rolls out a β-mixture of expert and learner, labels every visited state with the "
        "expert's action, writes the round as RUN_DIR/rounds/round-NN.mcap and retrains BC on everything so far. With "
        "--mode takeover (HG-DAgger) the learner drives until the expert takes the controls, and BC learns from the "
        "steps the expert drove. Each round file records who drove every step, the learner's proposed and the executed "
        "action (/intervention channels; `imitation info RUN_DIR` shows the rate by round). A person as the expert "
        "(keyboard, gamepad) sees a window: P pauses, - and = halve and double the speed, Esc stops (the round's "
        "finished episodes are kept; --resume continues the round).",
    )
    dagger.add_argument("--env", required=True, metavar="ID", help="gymnasium environment id")
    dagger.add_argument(
        "--expert",
        required=True,
        metavar="SPEC",
        help="scripted, standin (a scripted person who takes over when the state turns risky; CartPole), keyboard "
        "(discrete actions), gamepad (continuous actions; arrow keys without one), a run directory, or sb3:ZIP",
    )
    _add_speed(dagger)
    dagger.add_argument(
        "--demos",
        nargs="+",
        metavar="F.mcap",
        help="expert demos to start from (optional; they stand for the expert-only first round, so round 1 runs at "
        "the schedule's second β)",
    )
    _add_pixel_arguments(dagger, "the learner sees")
    add_flags(dagger, DAggerConfig)
    _add_workers(dagger, "each round's episodes, each worker writing its own shard of the round")
    _add_run_output(dagger)
    _add_resume(dagger)
    dagger.set_defaults(handler=cmd_train_dagger)

    irl = algorithms.add_parser(
        "irl",
        help="IRL: recover a reward from demos (tabular maxent/mce, continuous gcl, airl, gail, apprenticeship)",
        description="Maximum-entropy inverse RL. maxent (Ziebart 2008, deterministic dynamics) and mce (maximum causal "
        "entropy, any dynamics) need a tabular env with known dynamics (imitation/GridWorld8x8-v0, ...); gcl (guided cost "
        "learning) works on continuous envs and trains PPO on the reward as it learns it; so do the adversarial methods, airl "
        "(Fu et al. 2018: a discriminator structured by the policy's density and a shaping potential, whose state-only "
        "reward g is recovered) and gail (Ho & Ermon 2016: a free discriminator, PPO on −log(1 − D); its policy is the "
        "product, its discriminator a reward only with that caveat). apprenticeship (Abbeel & Ng "
        "2004, projection method) matches the demos' feature expectations with a mixture of policies: exactly on a "
        "tabular env, with PPO as the solver on Box observations. The run directory holds the reward model, for `train "
        "ppo --reward RUN_DIR`.",
    )
    irl.add_argument(
        "--method",
        choices=["maxent", "mce", "gcl", "airl", "gail", "apprenticeship"],
        default="mce",
        help="the IRL algorithm (default: mce)",
    )
    irl.add_argument("--env", required=True, metavar="ID", help="gymnasium environment id")
    irl.add_argument("--demos", required=True, nargs="+", metavar="F.mcap", help="expert demo files of that env")
    from imitation.algorithms import adversarial_config, apprenticeship_config, gcl_config, maxent_irl_config

    add_flags(irl, MaxEntIRLConfig, label=maxent_irl_config.LABEL)
    add_flags(irl, GCLConfig, label=gcl_config.LABEL)
    add_flags(irl, AdversarialConfig, label=adversarial_config.LABEL)
    add_flags(
        irl,
        PPOConfig,
        only=("total_steps",),
        label="gcl/airl/gail",
        default_texts={"total_steps": "the env's preset, 200000 where none"},
    )
    add_flags(irl, ApprenticeshipConfig, label=apprenticeship_config.LABEL)
    irl.add_argument(
        "--warm-start",
        metavar="RUN_DIR",
        help="airl/gail: start the discriminator (AIRL's g and h, GAIL's D) from a finished run's of the same method "
        "and networks, the policy from scratch: its negatives then include the states a fresh policy passes through "
        "on that reward (default: a fresh discriminator)",
    )
    _add_workers(irl, "PPO's rollouts (gcl, airl, gail)")
    _add_run_output(irl)
    _add_resume(irl)
    irl.set_defaults(handler=cmd_train_irl)

    evaluate = commands.add_parser(
        "eval", help="evaluate a policy or a recovered reward", description="Evaluate a trained policy or reward."
    )
    targets = evaluate.add_subparsers(dest="target", required=True, metavar="TARGET")
    policy = targets.add_parser(
        "policy", help="return of a run's policy", description="Mean, std, min and max return of a run directory's policy."
    )
    policy.add_argument("run", metavar="RUN_DIR", help="a PPO, BC or DAgger run directory")
    policy.add_argument("--env", required=True, metavar="ID", help="gymnasium environment id")
    add_flags(policy, PolicyEvaluationConfig)
    policy.add_argument("--json", action="store_true", help="print one JSON object")
    policy.set_defaults(handler=cmd_eval_policy)

    reward = targets.add_parser(
        "reward",
        help="is a recovered reward any good? EPIC, retraining and controls",
        description="Judge a recovered reward three ways beside two controls (a constant reward and a random network): "
        "EPIC distance and Pearson correlation to the true reward (exact on tabular MDPs, sampled on continuous envs), "
        "and the true return of policies retrained from scratch on it (PPO for continuous envs, the exact soft-optimal "
        "policy on tabular ones), normalised between a random policy (0) and the demos (1). Writes metrics.json, plots "
        "and report.md to --out.",
    )
    reward.add_argument("run", metavar="RUN_DIR", help="a reward run directory (`train irl`)")
    reward.add_argument("--env", required=True, metavar="ID", help="gymnasium environment id")
    add_flags(reward, RewardEvaluationConfig)
    _add_workers(reward, "the retrainings as Ray tasks (instead of --jobs local processes)")
    reward.add_argument("--out", metavar="DIR", help="where the evaluation goes (default: RUN_DIR/eval-reward)")
    reward.add_argument("--json", action="store_true", help="print one JSON object")
    reward.add_argument("--quiet", action="store_true", help="no progress bar")
    reward.set_defaults(handler=cmd_eval_reward)

    demo = commands.add_parser(
        "demo",
        help="the whole chain on the bundled data, with one report",
        description="Bundled demos → behavioural cloning and DAgger (CartPole-v1) → MaxEnt IRL on a gridworld and guided "
        "cost learning on fixed-horizon CartPole → PPO from scratch on the recovered reward → eval policy and eval reward, "
        "offline, in about three minutes on 2 cores; writes DIR/report.md with every result and plot.",
    )
    demo.add_argument("--out", default="demo-output", metavar="DIR", help="output directory (default: demo-output)")
    demo.add_argument("--datasets", metavar="DIR", help="where the bundled datasets are (default: the repository's datasets/)")
    demo.add_argument(
        "--quick",
        action="store_true",
        help="a one-minute smoke run: every training cut short (its learning results mean nothing)",
    )
    demo.add_argument("--json", action="store_true", help="print one JSON object")
    demo.add_argument("--quiet", action="store_true", help="no progress output")
    demo.set_defaults(handler=cmd_demo)

    sweep = commands.add_parser(
        "sweep",
        help="hyperparameter sweep over a train command's flags with Ray Tune (random or Optuna search, ASHA)",
        description="Run a train command many times with flags drawn from a search space (random search or Optuna), "
        "each trial in a Ray worker into its own run directory, stopping poor trials early with ASHA. Writes DIR/results.csv "
        "and DIR/results.md (one row per trial: flags, metric, steps run, how it ended, run directory) and DIR/best, a copy "
        "of the best finished trial's run directory. After Ctrl-C, the same command continues the sweep without running "
        "its finished trials again. Needs the optional extra: pip install 'imitation-mcap[ray]'.",
    )
    sweep.add_argument(
        "config",
        metavar="CONFIG.yaml",
        help="the sweep: train command, fixed flags (args), search space (space), metric, search, trials, scheduler "
        "(docs/SCALING.md; an example: docs/sweeps/bc-cartpole.yaml)",
    )
    sweep.add_argument(
        "--out",
        metavar="DIR",
        help="the sweep's folder; give the same one to continue an interrupted sweep (default: sweeps/ and the config's "
        "name without .yaml)",
    )
    sweep.add_argument(
        "--ray-address",
        default="local",
        metavar="ADDR",
        help="local (a Ray started on this machine for the sweep), auto (the cluster this machine belongs to) or "
        "HOST:PORT; on a cluster DIR must be on storage every node shares (default: local)",
    )
    sweep.add_argument(
        "--cpus",
        type=int,
        metavar="C",
        help="with a local Ray: the CPUs the trials share, each taking the config's cpus_per_trial (default: every core)",
    )
    sweep.add_argument("--json", action="store_true", help="print one JSON object with the results")
    sweep.set_defaults(handler=cmd_sweep)
    return parser


def _sigterm_as_interrupt() -> None:
    """SIGTERM (docker stop, Slurm preemption) takes Ctrl-C's path: writers close with their
    finished episodes, trainers save a checkpoint. It goes to whatever handles SIGINT at that
    moment (a writer or trainer defers it to a safe point), and stops the process even where
    SIGINT is ignored (a background job of a script)."""

    def on_sigterm(signum: int, frame: Any) -> None:
        handler = signal.getsignal(signal.SIGINT)
        if callable(handler):
            handler(signal.SIGTERM, frame)
        else:
            raise KeyboardInterrupt

    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, on_sigterm)


def _until_failure(args: argparse.Namespace, handler: Callable[[argparse.Namespace], int]) -> int:
    """The command; once it fails, SIGTERM no longer raises Ctrl-C in the middle of the clean-up
    and the report of why (a failing torchrun job terminates its other ranks at that moment)."""
    try:
        _apply_limits(args.limit)
        return handler(args)
    except BaseException:
        _sigterm_as_exit()
        raise


def _sigterm_as_exit() -> None:
    """Once the command has done its work, SIGTERM ends the process as it would any other
    (torchrun terminates the ranks that are left when one fails): raised as Ctrl-C there, it
    would interrupt the interpreter's clean-up with a traceback."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, signal.SIG_DFL)


def _apply_limits(assignments: list[str]) -> None:
    """The environment's limits, then the command line's; passed on to child processes. A
    command's time for remote reading starts here."""
    from imitation.data.mcap.remote_reads import restart_command_clock
    from imitation.limits import limits_from_environment, set_limit

    restart_command_clock()
    limits_from_environment()
    for assignment in assignments:
        set_limit(assignment)
    if assignments:
        os.environ["IMITATION_LIMITS"] = ",".join(filter(None, [os.environ.get("IMITATION_LIMITS", ""), *assignments]))


def _one_line(text: str) -> str:
    """One line, cut to a readable length, even if a message quotes a long multi-line error."""
    line = " ".join(part.strip() for part in text.splitlines() if part.strip())
    return line if len(line) <= MAX_ERROR_CHARS else line[: MAX_ERROR_CHARS - 1] + "…"


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    subcommand = getattr(args, "algorithm", None) or getattr(args, "target", None)
    args.command_key = f"{args.command} {subcommand}" if subcommand else args.command
    handler: Callable[[argparse.Namespace], int] = args.handler
    _sigterm_as_interrupt()
    try:
        return _run_handler(args, handler)
    finally:
        _sigterm_as_exit()


def _run_handler(args: argparse.Namespace, handler: Callable[[argparse.Namespace], int]) -> int:
    try:
        return _until_failure(args, handler)
    except ConfigError as error:
        print("error: " + _one_line(_flag_message(error, args)), file=sys.stderr)
        return EXIT_ERROR
    except ImitationError as error:
        print("error: " + _one_line(str(error)), file=sys.stderr)
        return EXIT_ERROR
    except OSError as error:  # a write the writer did not wrap: still one line, naming the file
        from imitation.output import os_error

        print("error: " + _one_line(str(os_error(error.filename or "output", error, "cannot read or write"))), file=sys.stderr)
        return EXIT_ERROR
    except MemoryError:
        print(
            "error: out of memory; train on fewer demo files, with a smaller --batch-size or network, or on a machine with "
            "more memory",
            file=sys.stderr,
        )
        return EXIT_ERROR
    except KeyboardInterrupt as interrupt:
        # A trainer stopped at a checkpoint says where it is and how to resume.
        print(f"interrupted: {interrupt}" if str(interrupt) else "interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())
