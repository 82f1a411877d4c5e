"""The command line generated from the configs (issue 52): each flag is declared once, beside its
config field (imitation/flags.py), and the commands built from configs have exactly one flag per
field and one field per flag."""

from __future__ import annotations

import argparse
from dataclasses import dataclass

import pytest

import cli
from imitation.train_commands import all_commands
from imitation.errors import ImitationError
from imitation.flags import NESTED, add_flags, flag, flag_name, flag_of, flagged, given, hidden_sizes, nested


def commands(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()) -> dict[str, argparse.ArgumentParser]:
    """Every leaf command of the command line, by its words (`train bc`)."""
    found = {}
    for name, sub in cli._subcommands(parser).items():
        if any(isinstance(action, argparse._SubParsersAction) for action in sub._actions):
            found |= commands(sub, (*path, name))
        else:
            found[" ".join((*path, name))] = sub
    return found


def config_flags(config: type, only: tuple[str, ...] | None = None) -> dict[str, set[str]]:
    """Option string → the names of the fields it sets, over `config` and its nested configs."""
    found: dict[str, set[str]] = {}
    for field in flagged(config):
        if only is None or field.name in only:
            found.setdefault(flag_name(field), set()).add(field.name)
    for field in config.__dataclass_fields__.values():
        if NESTED in field.metadata and (only is None or field.name in only):
            for option, names in config_flags(type(field.default_factory()), field.metadata[NESTED]).items():
                found.setdefault(option, set()).update(names)
    return found


CONFIGURED = {name: parser for name, parser in commands(cli.make_parser()).items() if parser.get_default("configs")}


def test_the_commands_with_settings_take_their_flags_from_their_configs() -> None:
    from imitation.train_commands import LEARNERS

    commands = all_commands()
    handled = set(cli.HANDLERS) | {f"train {name}" for name in LEARNERS}  # every train command runs its learner
    assert set(CONFIGURED) == set(commands) and set(commands) == handled


@pytest.mark.parametrize("name", sorted(CONFIGURED))
def test_each_config_field_has_one_flag_and_each_flag_one_field(name: str) -> None:
    """Within each config a command takes flags from; across them a flag may set fields of one
    name (a seed) or, in `train irl`, the field its method's config calls it (--steps: the PPO
    steps of gcl/airl/gail, the solver steps per iteration of apprenticeship)."""
    parser = CONFIGURED[name]
    options = {option: action for action in parser._actions for option in action.option_strings}
    options |= {action.dest: action for action in parser._actions if not action.option_strings}  # positional
    for config, only, fill in parser.get_default("configs"):
        for option, fields in config_flags(config, only).items():
            assert option in options, f"{name}: {config.__name__}'s {sorted(fields)} has no flag {option}"
            assert len(fields) == 1, f"{name}: {option} sets {sorted(fields)} of {config.__name__}"
            dest = options[option].dest
            assert dest == option.lstrip("-").replace("-", "_")
            if not fill:  # a config's flag not given leaves its default, or a preset's value, to the job
                assert parser.get_default(dest) is None, f"{name}: {option}"
    declared = {option for config, only, _ in parser.get_default("configs") for option in config_flags(config, only)}
    assert set(options) - {"-h", "--help"} == declared, f"{name}: flags that are no field's"


@dataclass(kw_only=True)
class Inner:
    width: int = flag(3, metavar="W", help="width")
    depth: int = flag(1, help="depth")


@dataclass(kw_only=True)
class Toy:
    env_id: str = flag(name="--env", help="the env")
    rate: float = flag(0.5, name="--lr", help="the rate")
    layers: list[int] = flag(parse=hidden_sizes, help="the layers", default_factory=lambda: [4, 4])
    fast: bool = flag(False, help="go fast")
    mode: str = flag("a", choices=("a", "b"), help="the mode")
    size: int | None = flag(None, convert=lambda text: int(text) * 2, parse=str, help="the size", default_text="as given")
    hidden: int = 7
    inner: Inner = nested(("width",), lambda: Inner(width=5))


def toy_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="toy")
    add_flags(parser, Toy)
    return parser


def test_flags_are_built_from_the_fields_types_defaults_and_help() -> None:
    parser = toy_parser()
    helps = {option: action.help for action in parser._actions for option in action.option_strings}
    assert helps == {
        "-h": "show this help message and exit",
        "--help": "show this help message and exit",
        "--env": "the env",
        "--lr": "the rate (default: 0.5)",
        "--layers": "the layers (default: 4,4)",
        "--fast": "go fast (default: off)",
        "--mode": "the mode (default: a)",
        "--size": "the size (default: as given)",
        "--width": "width (default: 5)",  # the nested instance's default, not the class's
    }
    args = parser.parse_args(["--env", "E", "--lr", "0.25", "--layers", "linear", "--fast", "--size", "21", "--width", "9"])
    assert Toy(**given(args, Toy)) == Toy(env_id="E", rate=0.25, layers=[], fast=True, size=42, inner=Inner(width=9, depth=1))
    assert Toy(**given(parser.parse_args(["--env", "E"]), Toy)) == Toy(env_id="E", inner=Inner(width=5))


@pytest.mark.parametrize(
    ("argv", "said"),
    [
        (["--env", "E", "--lr", "nan"], "argument --lr: expected a finite number, got 'nan'"),
        (["--env", "E", "--mode", "c"], "argument --mode: invalid choice: 'c' (choose from 'a', 'b')"),
        ([], "the following arguments are required: --env"),
    ],
)
def test_bad_flag_text_and_a_missing_required_flag_are_usage_errors(argv: list[str], said: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exited:
        toy_parser().parse_args(argv)
    assert exited.value.code == 2 and capsys.readouterr().err.strip().endswith(f"toy: error: {said}")


def test_a_config_error_is_reported_with_the_flag_that_sets_the_field() -> None:
    sources = toy_parser().get_default("configs")
    assert sources == ((Toy, None, False),)
    assert flag_of(sources, "Toy", "rate") == "--lr"
    assert flag_of(sources, "Inner", "width") == "--width"
    assert flag_of(sources, "Inner", "depth") is None  # nested, but not one of the command's flags
    assert flag_of(sources, None, "layers") == "--layers" and flag_of(sources, "Other", "rate") is None


def test_a_field_whose_type_says_no_parser_needs_one() -> None:
    @dataclass
    class Untyped:
        points: list[float] = flag(help="points", default_text="none", default_factory=list)

    with pytest.raises(TypeError, match="Untyped.points: a flag of type list"):
        add_flags(argparse.ArgumentParser(), Untyped)


def test_converting_a_given_flag_may_fail_in_one_line() -> None:
    def refuse(text: str) -> int:
        raise ImitationError(f"--size {text}: no")

    @dataclass
    class Refusing:
        size: int | None = flag(None, parse=str, convert=refuse, help="size", default_text="none")

    parser = argparse.ArgumentParser()
    add_flags(parser, Refusing)
    with pytest.raises(ImitationError, match="^--size 3: no$"):
        given(parser.parse_args(["--size", "3"]), Refusing)


def test_building_the_command_line_imports_no_heavy_library() -> None:
    """`imitation --help` and `train … --help` start fast (issue 52: ≤ 0.2 s) because the
    configs they read live in light modules: building every parser imports none of these."""
    import subprocess
    import sys

    from support import REPO

    heavy = ("torch", "numpy", "gymnasium", "mcap", "lerobot", "ray")
    probe = f"import sys, cli; cli.make_parser(); print(','.join(m for m in {heavy!r} if m in sys.modules))"
    result = subprocess.run([sys.executable, "-c", probe], cwd=REPO, capture_output=True, text=True, timeout=60, check=True)
    assert result.stdout.strip() == ""


def test_records_choices_are_what_the_writer_takes() -> None:
    """RecordConfig names the writer's compressions and codecs without importing it (mcap, numpy)."""
    from imitation.data.mcap.format import COMPRESSIONS
    from imitation.data.mcap.images import CODECS
    from imitation.jobs.record_config import RecordConfig

    choices = {field.name: field.metadata["imitation.flag"].choices for field in flagged(RecordConfig)}
    assert set(choices["compression"]) == set(COMPRESSIONS) and set(choices["image_codec"]) == set(CODECS)


def test_a_flag_several_variants_share_says_what_it_does_in_each() -> None:
    """`train irl`'s methods: one flag, its help per method, methods of the same text joined."""

    @dataclass
    class First:
        steps: int = flag(5, help="gradient steps")
        seed: int = flag(0, help="seed")

    @dataclass
    class Second:
        total: int = flag(9, name="--steps", help="environment steps")
        seed: int = flag(0, help="seed")

    parser = argparse.ArgumentParser()
    add_flags(parser, First, label="a/b")
    add_flags(parser, Second, label="c", default_texts={"total": "per env"})
    helps = {option: action.help for action in parser._actions for option in action.option_strings}
    assert helps["--steps"] == "a/b: gradient steps (default: 5); c: environment steps (default: per env)"
    assert helps["--seed"] == "a/b/c: seed (default: 0)"
    assert parser.get_default("configs") == ((First, None, False), (Second, None, False))
    args = parser.parse_args(["--steps", "7"])
    assert given(args, First) == {"steps": 7} and given(args, Second) == {"total": 7}


def test_a_default_the_value_does_not_say_needs_words() -> None:
    """None or an empty list says nothing in a help text; the field must say what it means."""

    @dataclass
    class Silent:
        widths: list[int] = flag(parse=hidden_sizes, help="widths", default_factory=list)

    with pytest.raises(TypeError, match=r"^widths: a flag whose default is \[\] needs default_text=$"):
        add_flags(argparse.ArgumentParser(), Silent)
