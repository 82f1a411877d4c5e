"""Command-line flags declared once, beside the dataclass fields they set.

A field becomes a flag by `flag(...)` in place of `dataclasses.field(...)`: its help text and,
where the field does not already say them, its name (`--field-name` by default), metavar,
choices, parser, arity or position. `add_flags` adds a dataclass's flags to an argparse parser.
For a learner's or job's config a flag not given stays None, so that the config's own default (or
a preset) applies, and `given` reads back the fields the user set; for a command's own options
(`fill`) argparse fills in the field's default. Either way the help names the default from the
field. The flags' argument types (`finite`, `seed`, `hidden_sizes`, …) refuse bad text where it
enters, as argparse usage errors (exit 2).

This module is imported by the light config modules that `imitation --help` loads: it imports
nothing heavier than argparse.

A small generator over `dataclasses.fields` rather than a library: draccus, the one already
installed (lerobot's, 0.11.6), makes exactly one `--field_name` option per field, without aliases
or positional arguments (its `FieldWrapper.option_strings`), while the command line keeps the names
its users' scripts use (`--lr`, `--hidden`, `--episodes-per-round`, `info FILE`); tyro,
jsonargparse and simple-parsing would be a new dependency for the same argparse underneath.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import typing
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import MISSING, Field
from typing import Any

FLAG = "imitation.flag"  # the key of a field's Flag in its dataclass metadata
NESTED = "imitation.nested"  # the key of a nested config's flagged fields (a tuple of names)


@dataclasses.dataclass(frozen=True)
class Flag:
    """How a config field appears on the command line.

    `parse` turns the text into a value as argparse reads it (argparse.ArgumentTypeError: a usage
    error); `convert` turns the parsed value into the field's value when the config is built (an
    ImitationError there is a one-line error, exit 1). `default_text` is what the help says when
    the field's default does not say it (None, or "auto"). `nargs` takes several values into a
    list field ("+", or a count), `append` one value per use of the flag, and a `positional`
    field is an argument without a dash, named by its field."""

    help: str
    name: str | None = None
    metavar: str | tuple[str, ...] | None = None
    parse: Callable[[str], Any] | None = None
    convert: Callable[[Any], Any] | None = None
    choices: tuple[str, ...] | None = None
    default_text: str | None = None
    nargs: str | int | None = None
    positional: bool = False
    append: bool = False


def flag(
    default: Any = MISSING,
    *,
    help: str,
    name: str | None = None,
    metavar: str | tuple[str, ...] | None = None,
    parse: Callable[[str], Any] | None = None,
    convert: Callable[[Any], Any] | None = None,
    choices: Sequence[str] | None = None,
    default_text: str | None = None,
    nargs: str | int | None = None,
    positional: bool = False,
    append: bool = False,
    default_factory: Callable[[], Any] | Any = MISSING,
) -> Any:
    """A dataclass field that is also a command-line flag."""
    described = Flag(
        help, name, metavar, parse, convert, tuple(choices) if choices else None, default_text, nargs, positional, append
    )
    return dataclasses.field(default=default, default_factory=default_factory, metadata={FLAG: described})


def nested(fields: Sequence[str], default_factory: Callable[[], Any]) -> Any:
    """A dataclass field holding another config, whose `fields` are flags of the outer command
    too, with the defaults of the instance `default_factory` makes (DAgger's BC per round)."""
    return dataclasses.field(default_factory=default_factory, metadata={NESTED: tuple(fields)})


def flag_name(field: Field) -> str:
    """The option string of a flagged field: its Flag's name, else `--field-name`; a positional
    argument's name is its field's."""
    described: Flag = field.metadata[FLAG]
    if described.positional:
        return field.name
    return described.name or "--" + field.name.replace("_", "-")


def flagged(config: type) -> list[Field]:
    """The fields of a config dataclass that are flags, in declaration order."""
    return [field for field in dataclasses.fields(config) if FLAG in field.metadata]


# A config, the names of its fields that are flags (None: all), and whether argparse fills in
# their defaults (a command's own options) or leaves a flag not given None (a config's settings,
# which presets and other configs may complete).
Source = tuple[type, tuple[str, ...] | None, bool]
SOURCES = "configs"  # the parser default that records the sources of a command's flags


def add_flags(
    parser: argparse.ArgumentParser,
    config: type,
    only: Iterable[str] | None = None,
    *,
    label: str | None = None,
    default_texts: Mapping[str, str] | None = None,
    helps: Mapping[str, str] | None = None,
    fill: bool = False,
    choices: Mapping[str, Sequence[str]] | None = None,
) -> None:
    """Add the flags of `config` (those of the fields named in `only`, if given) and of its nested
    configs to `parser`, and record `config` among the parser's sources (its `configs` default,
    which `flag_of` reads). A flag not given is None, so that the config's own default, or a
    preset, applies; with `fill` (a command's own options) argparse fills in the field's default.
    `label` names the variants of a command the flags are for (`train irl`'s methods): the help
    then says, per label, what the flag does there. `helps`, `default_texts` and `choices` replace
    a field's help, how it names its default and its choices, for this command. A flag the parser
    already has (a seed shared by two configs of one command) is not added again: it sets both
    fields."""
    chosen = None if only is None else tuple(only)
    parser.set_defaults(**{SOURCES: (*(parser.get_default(SOURCES) or ()), (config, chosen, fill))})
    _add(parser, config, chosen, None, _Wording(label, default_texts or {}, helps or {}, fill, choices or {}))


@dataclasses.dataclass(frozen=True)
class _Wording:
    """How one command words and fills a dataclass's flags (`add_flags`' keywords)."""

    label: str | None
    default_texts: Mapping[str, str]
    helps: Mapping[str, str]
    fill: bool
    choices: Mapping[str, Sequence[str]]


def _add(parser: argparse.ArgumentParser, config: type, only: Iterable[str] | None, defaults: Any, wording: _Wording) -> None:
    """The flags of `config` (help naming the defaults of the instance `defaults`, else the
    fields' own) and of its nested configs."""
    types = typing.get_type_hints(config)
    for field in _chosen(config, only):
        if NESTED in field.metadata:
            inner = getattr(defaults, field.name) if defaults is not None else _field_default(field)
            _add(parser, type(inner), field.metadata[NESTED], inner, wording)
            continue
        option = flag_name(field)
        described: Flag = field.metadata[FLAG]
        value = getattr(defaults, field.name) if defaults is not None else _field_default(field)
        required = value is MISSING
        said = wording.default_texts.get(field.name) or (None if required else _default_text(described, value, field.name))
        text = wording.helps.get(field.name, described.help)
        text = text if said is None else f"{text} (default: {said})"
        if option in parser._option_string_actions:
            if wording.label is not None:
                _describe(parser._option_string_actions[option], wording.label, text)
            continue
        default = None if required or not wording.fill else value
        kind = _base_type(types[field.name])
        if described.nargs is not None or described.append:
            kind = _base_type(typing.get_args(_without_none(types[field.name]))[0])
        if kind is bool:
            action = parser.add_argument(option, dest=_dest(option), action="store_true", default=default, help=text)
        else:
            parse = described.parse or _PARSERS.get(kind)
            if parse is None:
                raise TypeError(f"{config.__name__}.{field.name}: a flag of type {types[field.name]} needs parse=")
            options: dict[str, Any] = dict(
                type=parse,
                choices=wording.choices.get(field.name, described.choices),
                nargs=described.nargs,
                metavar=described.metavar,
                help=text,
            )
            if described.positional:
                action = parser.add_argument(option, **options)
            else:
                if described.append:
                    options["action"] = "append"
                action = parser.add_argument(option, dest=_dest(option), required=required, default=default, **options)
        if wording.label is not None:
            _describe(action, wording.label, text)


def _describe(action: argparse.Action, label: str, text: str) -> None:
    """Add what the flag does for the variants `label` to its help: `labels: text; …`, the labels
    of the same text joined."""
    parts: list[list[str]] = getattr(action, _PARTS, [])
    for part in parts:
        if part[1] == text:
            part[0] += "/" + label
            break
    else:
        parts.append([label, text])
    setattr(action, _PARTS, parts)
    action.help = "; ".join(f"{labels}: {said}" for labels, said in parts)


_PARTS = "imitation_help_parts"


def given(args: argparse.Namespace, config: type, only: Iterable[str] | None = None) -> dict[str, Any]:
    """The fields of `config` whose flags were given on the command line, converted; a nested
    config is its default instance with its given fields replaced."""
    values = {}
    for field in _chosen(config, only):
        if NESTED in field.metadata:
            inner = _field_default(field)
            values[field.name] = dataclasses.replace(inner, **given(args, type(inner), field.metadata[NESTED]))
            continue
        value = getattr(args, _dest(flag_name(field)), None)
        if value is not None:
            convert = field.metadata[FLAG].convert
            values[field.name] = convert(value) if convert is not None else value
    return values


def flag_of(sources: Iterable[Source], owner: str | None, field_name: str) -> str | None:
    """The flag that sets field `field_name` of the config class named `owner` among the
    `sources` a parser recorded and the configs nested in them (owner None: of any of them),
    or None when no flag sets it."""
    for config, only in _with_nested(sources):
        if owner is not None and config.__name__ != owner:
            continue
        for field in _chosen(config, only):
            if field.name == field_name and FLAG in field.metadata:
                return flag_name(field)
    return None


def _chosen(config: type, only: Iterable[str] | None) -> list[Field]:
    """The flagged and nested fields of `config`, those named in `only` if given."""
    wanted = None if only is None else set(only)
    return [
        field
        for field in dataclasses.fields(config)
        if (FLAG in field.metadata or NESTED in field.metadata) and (wanted is None or field.name in wanted)
    ]


def _with_nested(sources: Iterable[Source]) -> list[tuple[type, tuple[str, ...] | None]]:
    """The configs of `sources` and every config nested in them, with the names of their fields
    that are flags."""
    found: list[tuple[type, tuple[str, ...] | None]] = []
    pending = [(config, only) for config, only, _ in sources]
    while pending:
        config, only = pending.pop(0)
        found.append((config, only))
        for field in _chosen(config, only):
            if NESTED in field.metadata:
                pending.append((type(_field_default(field)), field.metadata[NESTED]))
    return found


def _dest(option: str) -> str:
    return option.lstrip("-").replace("-", "_")


def _base_type(annotation: Any) -> Any:
    """`int` for `int | None`, `list` for `list[int]`: the type a flag's text becomes."""
    annotation = _without_none(annotation)
    return typing.get_origin(annotation) or annotation


def _without_none(annotation: Any) -> Any:
    """`int` for `int | None`; any other annotation as it is."""
    arguments = [argument for argument in typing.get_args(annotation) if argument is not type(None)]
    if typing.get_origin(annotation) in (typing.Union, _UNION) and len(arguments) == 1:
        return arguments[0]
    return annotation


_UNION = type(int | None)


def _field_default(field: Field) -> Any:
    """The value a field takes when not given (MISSING when it must be given)."""
    if field.default_factory is not MISSING:
        return field.default_factory()
    return field.default


def _default_text(described: Flag, default: Any, name: str) -> str:
    if described.default_text is not None:
        return described.default_text
    if isinstance(default, bool):
        return "on" if default else "off"
    if default is None or default == []:
        raise TypeError(f"{name}: a flag whose default is {default!r} needs default_text=")
    if isinstance(default, list):
        return ",".join(str(item) for item in default)
    return str(default)


def finite(text: str) -> float:
    """A float option: NaN and ±inf are refused where they enter, not deep inside training."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text[:100]!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text[:100]!r}")
    return value


def quality(text: str) -> int:
    """An image codec's quality: a whole number from 1 to 100."""
    if not text.strip().isdigit() or not 1 <= int(text) <= 100:
        raise argparse.ArgumentTypeError(f"expected a whole number from 1 to 100, got {text[:100]!r}")
    return int(text)


def seconds(text: str) -> float:
    """A positive, finite number of seconds (below a million: beyond that it is a typo)."""
    value = finite(text)
    if not 0 < value < 1e6:
        raise argparse.ArgumentTypeError(f"expected a positive number of seconds, got {text[:100]!r}")
    return value


def seed(text: str) -> int:
    """A seed: a whole number in the range every generator a job seeds accepts (numpy's legacy
    one takes none below 0 or from 2^32 on; torch none from 2^64 on)."""
    from imitation.seeding import seed_problem

    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text[:100]!r}") from None
    if (problem := seed_problem(value)) is not None:
        raise argparse.ArgumentTypeError(problem)
    return value


def speed(text: str) -> float:
    """A speed factor of a person's window, from 1/8 to 4 times real time."""
    value = finite(text)
    if not 0.125 <= value <= 4:
        raise argparse.ArgumentTypeError(f"expected a factor from 0.125 to 4, got {text[:100]!r}")
    return value


def megabytes(text: str) -> int:
    """A size in megabytes (MiB, fractions allowed) → bytes; at least one byte."""
    value = finite(text)
    if value * 2**20 < 1:
        raise argparse.ArgumentTypeError(f"expected a positive number of megabytes, got {text[:100]!r}")
    return int(value * 2**20)


def indices(text: str) -> list[int]:
    """Positions such as `4` or `2,5`: distinct whole numbers from 0."""
    try:
        values = [int(part) for part in text.split(",") if part.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated positions such as 2,5, got {text!r}") from None
    if any(value < 0 for value in values) or len(set(values)) != len(values):
        raise argparse.ArgumentTypeError(f"positions must be distinct and at least 0, got {text!r}")
    return values


def hidden_sizes(text: str) -> list[int]:
    """Layer widths such as `64,64`, or `linear` for none."""
    if text == "linear":
        return []
    try:
        sizes = [int(part) for part in text.split(",") if part.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated layer widths such as 64,64, got {text!r}") from None
    if any(size < 1 for size in sizes):
        raise argparse.ArgumentTypeError(f"layer widths must be positive, got {text!r}")
    return sizes


def names(text: str) -> list[str]:
    """A comma-separated list of names, e.g. `pixels,state`."""
    parts = [name.strip() for name in text.split(",")]
    if not all(parts):
        raise argparse.ArgumentTypeError(f"{text!r}: give names separated by commas, e.g. pixels,state")
    return parts


# The argument type of a flag whose field's type says it.
_PARSERS: dict[Any, Callable[[str], Any]] = {int: int, float: finite, str: str}
