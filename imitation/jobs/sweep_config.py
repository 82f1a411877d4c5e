"""The YAML file of `imitation sweep`: which `train` command, its fixed flags, the search space
over its flags, the metric, the search algorithm and the early-stopping scheduler.

    command: train bc
    args: {demos: datasets/CartPole-v1.mcap, epochs: 20}
    space:
      lr: {loguniform: [1.0e-4, 1.0e-1]}
      hidden: {choice: ["16,16", "64,64", "256,256"]}
    trials: 8
    scheduler: {asha: {grace_period: 2}}

Keys of `args` and `space` are the command's flags without their dashes, values what one would
type after them. The file is read and every trial's command line parsed by the command line's
own parser before Ray starts, so that a typo fails at once; each problem is one line naming the
file and the key. docs/SCALING.md is the reference of every key.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from imitation.data.convert.yaml_bounded import read_yaml_file
from imitation.errors import ImitationError
from imitation.seeding import seed_problem

KEYS = (
    "command",
    "args",
    "space",
    "metric",
    "mode",
    "scope",
    "search",
    "trials",
    "scheduler",
    "seed",
    "cpus_per_trial",
    "gpus_per_trial",
)
RANGES = ("uniform", "loguniform", "randint")  # [low, high], both ends included
CHOICES = ("choice", "grid")  # a list of values; grid runs every one (times `trials`)
SEARCHES = ("random", "optuna")
# Flags the sweep sets for every trial: its run directory, no progress bar, no JSON.
SWEEP_FLAGS = ("out", "quiet", "json", "resume", "help")
Scalar = str | int | float | bool
RUN_PLACEHOLDER = "OUT/runs/TRIAL"


@dataclass(frozen=True)
class CommandLine:
    """What reading a sweep needs of the command line, which the jobs layer may not import: each
    `train` command with its flags (without dashes), argparse's one-line objection to a command
    line (None when it parses), and the metric a command with fixed flags optimises unless the
    file names one (None where the file must: `imitation.train_commands.default_metric`)."""

    commands: dict[str, frozenset[str]]
    problem: Callable[[list[str]], str | None]
    metric: Callable[[str, dict[str, Any]], tuple[str, str, str] | None]


@dataclass(frozen=True)
class Distribution:
    """One flag's search space: `kind` is one of RANGES with `values` (low, high), or one of
    CHOICES with `values` the choices."""

    kind: str
    values: tuple[Scalar, ...]

    @property
    def size(self) -> int:
        """How many trials one sample of it makes: a grid runs each of its values."""
        return len(self.values) if self.kind == "grid" else 1

    def to_json(self) -> dict[str, list[Scalar]]:
        return {self.kind: list(self.values)}


@dataclass(frozen=True)
class Asha:
    """ASHA's settings, in the learner's steps (BC's epochs, PPO's updates, DAgger's rounds): every
    trial runs `grace_period` steps before it may be stopped, a `1/reduction_factor` share goes on
    at each rung, and none runs past `max_steps` (None: each ends where its command ends it)."""

    grace_period: int = 1
    reduction_factor: int = 2
    max_steps: int | None = None


@dataclass(frozen=True)
class SweepConfig:
    """A sweep file, read and checked (`read_sweep_config`)."""

    path: Path
    command: str
    args: dict[str, Scalar | list[Scalar]]
    space: dict[str, Distribution]
    metric: str
    mode: str
    scope: str
    search: str = "random"
    trials: int = 10
    asha: Asha | None = None
    seed: int = 0
    cpus_per_trial: float = 1.0
    gpus_per_trial: float = 0.0
    seeds_trials: bool = True  # no `seed` among args or space: the sweep's seed is each trial's

    @property
    def total_trials(self) -> int:
        return self.trials * math.prod(distribution.size for distribution in self.space.values())

    def argv(self, params: dict[str, Any], run: str) -> list[str]:
        """A trial's command line for the values `params` of the searched flags, into run directory `run`."""
        words = self.command.split()
        for key, value in [*self.args.items(), *params.items()]:
            words += _flag_words(key, value)
        return [*words, *(["--seed", str(self.seed)] if self.seeds_trials else []), "--out", run, "--quiet"]

    def to_json(self) -> dict[str, Any]:
        """What makes two sweeps the same experiment (the path aside): compared on resume."""
        return {
            "command": self.command,
            "args": self.args,
            "space": {key: distribution.to_json() for key, distribution in self.space.items()},
            "metric": self.metric,
            "mode": self.mode,
            "scope": self.scope,
            "search": self.search,
            "trials": self.trials,
            "asha": None if self.asha is None else vars(self.asha),
            "seed": self.seed,
        }


def read_sweep_config(path: str | Path, command_line: CommandLine) -> SweepConfig:
    """The sweep file at `path`, checked: its keys, its flags (those of its command), its
    distributions, and every trial's command line through the command line's parser."""
    path = Path(path)
    document = read_yaml_file(path, "sweep config")
    if not isinstance(document, dict):
        raise ImitationError(f"{path}: a sweep config is a YAML mapping (command, args, space, ...), not {_kind(document)}")
    where = _Where(path)
    for key in document:
        if key not in KEYS:
            raise ImitationError(f"{path}: unknown key {key!r}{_suggestion(str(key), KEYS)}; the keys are {', '.join(KEYS)}")
    command = _command(document.get("command"), command_line, where)
    flags = command_line.commands[command]
    args = {
        key: _fixed(value, where.at(f"args.{key}"))
        for key, value in _flag_mapping(document.get("args", {}), flags, where.at("args")).items()
    }
    space = {
        key: _distribution(value, where.at(f"space.{key}"))
        for key, value in _flag_mapping(document.get("space"), flags, where.at("space")).items()
    }
    if not space:
        raise ImitationError(f"{path}: space: give at least one flag to search over, such as lr with a loguniform range")
    if both := sorted(set(args) & set(space)):
        raise ImitationError(f"{path}: space.{both[0]}: the flag is also in args; give it in one place")
    metric, mode, scope = _metric(document, command, args, space, where, command_line.metric)
    search = _one_of(document.get("search", "random"), SEARCHES, where.at("search"))
    if search == "optuna" and (grids := [key for key, value in space.items() if value.kind == "grid"]):
        raise ImitationError(f"{path}: space.{grids[0]}: grid needs search: random (Optuna samples; use choice)")
    config = SweepConfig(
        path=path,
        command=command,
        args=args,
        space=space,
        metric=metric,
        mode=mode,
        scope=scope,
        search=search,
        trials=_integer(document.get("trials", 10), where.at("trials"), least=1),
        asha=_scheduler(document.get("scheduler", "none"), where.at("scheduler")),
        seed=_seed(document.get("seed", 0), where.at("seed")),
        cpus_per_trial=_positive(document.get("cpus_per_trial", 1), where.at("cpus_per_trial")),
        gpus_per_trial=_positive(document.get("gpus_per_trial", 0), where.at("gpus_per_trial"), zero=True),
        seeds_trials="seed" in flags and "seed" not in args and "seed" not in space,
    )
    _check_command_lines(config, command_line.problem)
    return config


@dataclass(frozen=True)
class _Where:
    """Where in the file a value is, for its messages: `FILE: KEY: problem`."""

    path: Path
    key: str = ""

    def at(self, key: str) -> _Where:
        return _Where(self.path, key)

    def error(self, problem: str) -> ImitationError:
        return ImitationError(f"{self.path}: {self.key}: {problem}")


def _command(value: Any, command_line: CommandLine, where: _Where) -> str:
    if value is None:
        raise where.at("command").error(f"missing: name the train command, one of {', '.join(command_line.commands)}")
    command = " ".join(str(value).split())
    if command not in command_line.commands:
        raise where.at("command").error(
            f"{str(value)[:100]!r} is not a train command{_suggestion(command, command_line.commands)}; "
            f"use one of {', '.join(command_line.commands)}"
        )
    return command


def _flag_mapping(value: Any, flags: frozenset[str], where: _Where) -> dict[str, Any]:
    """`args` or `space`: a mapping whose keys are flags of the command."""
    if value is None:
        raise where.error("missing: a mapping of the command's flags (without --)")
    if not isinstance(value, dict):
        raise where.error(f"a mapping of the command's flags (without --), not {_kind(value)}")
    for key in value:
        name = str(key)
        if name in SWEEP_FLAGS:
            raise where.at(f"{where.key}.{name}").error(
                "set by the sweep for every trial (its run directory is OUT/runs/TRIAL); leave it out"
            )
        if name not in flags:
            raise where.at(f"{where.key}.{name}").error(
                f"not a flag of this command{_suggestion(name.lstrip('-'), flags)}; its flags are {', '.join(sorted(flags))}"
            )
    return {str(key): item for key, item in value.items()}


def _fixed(value: Any, where: _Where) -> Scalar | list[Scalar]:
    """A fixed flag's value: one value, or a list for a flag that takes several (--demos)."""
    if isinstance(value, list) and value and all(_is_scalar(item) for item in value):
        return value
    if _is_scalar(value):
        return value
    raise where.error(f"a value (text, a number, true or false) or a list of values, not {_kind(value)}")


def _distribution(value: Any, where: _Where) -> Distribution:
    kinds = (*RANGES, *CHOICES)
    if not (isinstance(value, dict) and len(value) == 1 and next(iter(value)) in kinds):
        raise where.error(f"a distribution: one of {', '.join(f'{{{kind}: [...]}}' for kind in kinds)}, not {_shown(value)}")
    kind, values = next(iter(value.items()))
    if kind in CHOICES:
        if not (isinstance(values, list) and values and all(_is_scalar(item) for item in values)):
            raise where.error(f"{kind} takes a list of values (text, numbers, true or false), not {_shown(values)}")
        return Distribution(kind, tuple(values))
    if not (isinstance(values, list) and len(values) == 2):
        raise where.error(f"{kind} takes [low, high], not {_shown(values)}")
    reader = _integer if kind == "randint" else _number
    low, high = (reader(item, where) for item in values)
    if not low < high:
        raise where.error(f"{kind} needs low < high, got [{low}, {high}]")
    if kind == "loguniform" and low <= 0:
        raise where.error(f"loguniform needs 0 < low, got {low}")
    return Distribution(kind, (low, high))


def _metric(
    document: dict[str, Any],
    command: str,
    args: dict[str, Any],
    space: dict[str, Distribution],
    where: _Where,
    default_metric: Callable[[str, dict[str, Any]], tuple[str, str, str] | None],
) -> tuple[str, str, str]:
    """(metric, mode, scope): the file's, or the command's default."""
    default = None if command == "train irl" and "method" in space else default_metric(command, args)
    metric = document.get("metric", default[0] if default is not None else None)
    if metric is None:
        raise where.at("metric").error(
            f"missing: {command} logs different rows for each --method; name the column to optimise"
        )
    if not (isinstance(metric, str) and metric):
        raise where.at("metric").error(f"the name of a column of the rows the command logs, not {_shown(metric)}")
    if default is not None and metric == default[0]:
        default_mode, default_scope = default[1], default[2]
    elif "mode" in document:
        default_mode, default_scope = "min", "last"
    else:
        raise where.at("mode").error(f"missing: say whether a lower (min) or higher (max) {metric} is better")
    mode = _one_of(document.get("mode", default_mode), ("min", "max"), where.at("mode"))
    scope = _one_of(document.get("scope", default_scope), ("best", "last"), where.at("scope"))
    return metric, mode, scope


def _scheduler(value: Any, where: _Where) -> Asha | None:
    if value in ("none", None):
        return None
    if value == "asha":
        return Asha()
    if not (isinstance(value, dict) and list(value) == ["asha"] and isinstance(value["asha"], dict | None)):
        raise where.error(
            f"none, asha, or {{asha: {{grace_period: N, reduction_factor: N, max_steps: N}}}}, not {_shown(value)}"
        )
    settings = value["asha"] or {}
    for key in settings:
        if key not in ("grace_period", "reduction_factor", "max_steps"):
            raise where.at(f"scheduler.asha.{key}").error("unknown; ASHA takes grace_period, reduction_factor and max_steps")
    asha = Asha(
        grace_period=_integer(settings.get("grace_period", 1), where.at("scheduler.asha.grace_period"), least=1),
        reduction_factor=_integer(settings.get("reduction_factor", 2), where.at("scheduler.asha.reduction_factor"), least=2),
        max_steps=None
        if settings.get("max_steps") is None
        else _integer(settings["max_steps"], where.at("scheduler.asha.max_steps"), least=1),
    )
    if asha.max_steps is not None and asha.max_steps < asha.grace_period:
        raise where.at("scheduler.asha.max_steps").error(f"must be at least grace_period ({asha.grace_period})")
    return asha


def _check_command_lines(config: SweepConfig, problem: Callable[[list[str]], str | None]) -> None:
    """Every trial's command line parses: the fixed flags with each searched flag at each value
    it can take (a range at both ends), the others at their first."""
    first = {key: distribution.values[0] for key, distribution in config.space.items()}
    if (found := problem(config.argv(first, RUN_PLACEHOLDER))) is not None:
        shown = " ".join(config.argv(first, RUN_PLACEHOLDER))
        raise ImitationError(f"{config.path}: the trials' command line {shown!r} fails: {found}")
    for key, distribution in config.space.items():
        for value in distribution.values[1:]:
            if (found := problem(config.argv(first | {key: value}, RUN_PLACEHOLDER))) is not None:
                raise ImitationError(f"{config.path}: space.{key}: {_shown(value)}: {found}")


def _flag_words(key: str, value: Scalar | list[Scalar]) -> list[str]:
    """`--key value` as typed: true is the bare flag, false leaves it out, a list gives several values."""
    if value is True:
        return [f"--{key}"]
    if value is False:
        return []
    if isinstance(value, list):
        return [f"--{key}", *(str(item) for item in value)]
    return [f"--{key}", str(value)]


def _integer(value: Any, where: _Where, *, least: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise where.error(f"a whole number, not {_shown(value)}")
    if least is not None and value < least:
        raise where.error(f"must be at least {least}, got {value}")
    return value


def _seed(value: Any, where: _Where) -> int:
    seed = _integer(value, where)
    if (problem := seed_problem(seed)) is not None:
        raise where.error(problem)
    return seed


def _number(value: Any, where: _Where) -> float:
    """A finite number; YAML reads 1e-4 (no dot) as text, so numeric text is taken too."""
    try:
        number = float(value) if not isinstance(value, bool) else math.nan
    except (TypeError, ValueError):
        number = math.nan
    if not math.isfinite(number):
        raise where.error(f"a finite number, not {_shown(value)}")
    return number


def _positive(value: Any, where: _Where, *, zero: bool = False) -> float:
    number = _number(value, where)
    if number < 0 or (number == 0 and not zero):
        raise where.error(f"must be {'at least 0' if zero else 'positive'}, got {value}")
    return number


def _one_of(value: Any, choices: tuple[str, ...], where: _Where) -> str:
    if value not in choices:
        raise where.error(f"one of {', '.join(choices)}, not {_shown(value)}")
    return str(value)


def _is_scalar(value: Any) -> bool:
    return isinstance(value, str | bool | int) or (isinstance(value, float) and math.isfinite(value))


def _kind(value: Any) -> str:
    return "nothing" if value is None else f"a {type(value).__name__}"


def _shown(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:79] + "…"


def _suggestion(name: str, known: Any) -> str:
    close = difflib.get_close_matches(name, list(known), n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""
