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
    from imitation.commands import ConvertOptions
    from imitation.data.convert.job import convert, inspect

    source_kind = ConvertOptions(**given(args, ConvertOptions)).source_kind  # --from, a Python keyword
    if args.inspect or args.write_map:
        if args.out or args.map or args.env or args.layout:
            args.parser.error("--inspect lists a bag's topics; it takes no --out, --map, --layout or --env")
        report = inspect(args.source, source=source_kind, write_map=args.write_map, ros_distro=args.ros_distro)
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
        source=source_kind,
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
    from imitation.data.export.formats import format_named

    target, destination = args.to
    exported = format_named(target)
    result = exported.export(args.file, destination, progress=not args.quiet)
    if args.json:
        _print_json(result)
    else:
        print(f"exported {args.file} to {destination}: {exported.summary(result)}")
    return 0


def cmd_train(args: argparse.Namespace) -> int:
    from imitation.train_commands import LEARNERS

    trained = LEARNERS[args.algorithm].train(args)
    if trained is None:
        return 0
    _print_warnings(trained.result.get("warnings", []))
    if args.json:
        _print_json(trained.result)
    else:
        print("\n".join(trained.lines()))
    return 0


def cmd_eval_policy(args: argparse.Namespace) -> int:
    from imitation.evaluation.task_measures import measures_line
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
    if measured := measures_line(result):
        print(measured)
    if "normalized_return" in result:
        reference = result["reference"]
        print(
            f"normalised return {result['normalized_return']:.3f} (0 = {reference['random_return']:.2f}, 1 = "
            f"{reference['expert_return']:.2f}: {reference['source']})"
        )
    if "no_normalized_return" in result:
        print(f"no normalised return: {result['no_normalized_return']}")
    if args.video:
        print(f"video of episode 0 (return {result['video']['return']:.2f}): {args.video}")
    return 0


def cmd_eval_reward(args: argparse.Namespace) -> int:
    import torch

    from imitation.jobs.evaluate_reward import evaluate_reward
    from imitation.jobs.evaluate_reward_config import RewardEvaluationConfig
    from imitation.train_commands import workers_of

    torch.set_num_threads(1)  # EPIC's many small reward calls: faster on one thread (bench/RESULTS.md)
    config = RewardEvaluationConfig(**given(args, RewardEvaluationConfig))
    out = args.out or str(Path(args.run) / "eval-reward")
    result = evaluate_reward(args.run, args.env, config, out, progress=not args.quiet, workers=workers_of(args))
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
    from imitation.jobs.sweep_config import read_sweep_config

    config = read_sweep_config(args.config, _command_line())
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


def _command_line() -> Any:
    """What a sweep reads of the command line (`imitation.jobs.sweep_config.CommandLine`)."""
    from imitation.jobs.sweep_config import CommandLine
    from imitation.train_commands import default_metric

    return CommandLine(commands=_train_commands(), problem=_train_problem, metric=default_metric)


def _train_commands() -> dict[str, frozenset[str]]:
    """Each `train` command with its flags, without dashes: what a sweep config may set."""
    return {
        f"train {name}": frozenset(
            option[2:] for action in parser._actions for option in action.option_strings if option[:2] == "--"
        )
        for name, parser in _subcommands(_subcommands(make_parser())["train"]).items()
    }


def _train_problem(argv: list[str]) -> str | None:
    """argparse's one-line objection to the command line `argv`, or None when it parses."""
    import contextlib
    import io

    stderr = io.StringIO()
    try:
        with contextlib.redirect_stderr(stderr):
            make_parser().parse_args(argv)
    except SystemExit:
        lines = stderr.getvalue().strip().splitlines()
        return lines[-1].split(": error: ", 1)[-1] if lines else "not a command line of imitation"
    return None


def _run_train(argv: list[str]) -> None:
    """Run the `train` command line `argv` in this process, as a sweep's trial does: a failure is
    raised as one line in the command line's words, not printed."""
    args = make_parser().parse_args(argv)
    args.command_key = f"{args.command} {args.algorithm}"
    _apply_limits([])  # the sweep's --limit reached this worker through IMITATION_LIMITS
    try:
        args.handler(args)
    except ConfigError as error:
        raise ImitationError(_flag_message(error, args)) from None


def _flag_message(error: ConfigError, args: argparse.Namespace) -> str:
    """A config error in the command line's words: the field named by the flag that sets it, a
    config flag or the command's own option of the field's name (`train irl --method`)."""
    flag = flags.flag_of(getattr(args, flags.SOURCES, ()), error.owner, error.field)
    if flag is None and error.field in vars(args):
        flag = "--" + error.field.replace("_", "-")
    return error.renamed(flag) if flag is not None else str(error)


HANDLERS: dict[str, Callable[[argparse.Namespace], int]] = {
    "record": cmd_record,
    "info": cmd_info,
    "recover": cmd_recover,
    "convert": cmd_convert,
    "export": cmd_export,
    "eval policy": cmd_eval_policy,
    "eval reward": cmd_eval_reward,
    "demo": cmd_demo,
    "sweep": cmd_sweep,
}


def make_parser() -> argparse.ArgumentParser:
    """The command line, built from its declarations (imitation/commands.py): each command's
    flags from the dataclasses it names, each with its handler here (every `train` command's
    `cmd_train`, which runs its learner from imitation/train_commands.py)."""
    from imitation.commands import GROUPS, Global
    from imitation.train_commands import all_commands

    parser = argparse.ArgumentParser(
        prog="imitation", description="Imitation learning on MCAP demonstration files: record, inspect, train, evaluate."
    )
    parser.add_argument("--version", action="version", version=f"imitation-mcap {__version__}")
    add_flags(parser, Global, fill=True)
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    groups: dict[str, Any] = {}
    for words, command in all_commands().items():
        *group, name = words.split()
        container = commands
        if group:
            if group[0] not in groups:
                summary, description, dest = GROUPS[group[0]]
                grouped = commands.add_parser(group[0], help=summary, description=description)
                groups[group[0]] = grouped.add_subparsers(dest=dest, required=True, metavar=dest.upper())
            container = groups[group[0]]
        sub = container.add_parser(name, help=command.help, description=command.description)
        for options in command.options() if callable(command.options) else command.options:
            add_flags(
                sub,
                options.config,
                options.only,
                label=options.label,
                default_texts=options.default_texts,
                helps=options.helps,
                fill=options.fill,
                choices=options.choices,
            )
        sub.set_defaults(handler=cmd_train if group == ["train"] else HANDLERS[words], parser=sub)
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
    args = make_parser().parse_args(argv)
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
