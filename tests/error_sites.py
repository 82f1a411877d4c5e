"""Every user-facing error message in the package and cli.py, found by an AST scan: the
templates of `raise ImitationError(...)` (and its subclasses), with each formatted value written
`{}`. A `ConfigError(field, problem, owner=...)` says "{field} {problem}", its field (or the flag
the command line puts in its place) a placeholder: its template is `"{} " + template(problem)`.
docs/ERRORS.md must list each one (tests/test_errors_catalogue.py)."""

from __future__ import annotations

import ast
import re
from dataclasses import dataclass
from pathlib import Path

ERROR_TYPES = {"ImitationError", "DemoFileError", "SpaceError", "TrainingInterrupted", "WriteError"}
# Helpers whose argument becomes (part of) an ImitationError message.
MESSAGE_HELPERS = {"fail": "{}: ", "Damage": ""}
# Errors whose message is "{field} {problem}": the field, named by the config or renamed to a flag by the CLI, varies.
FIELD_ERRORS = {"ConfigError"}


@dataclass(frozen=True)
class Site:
    path: str
    line: int
    template: str


def _template(node: ast.expr) -> str:
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return node.value
    if isinstance(node, ast.JoinedStr):
        parts = []
        for value in node.values:
            if isinstance(value, ast.Constant):
                parts.append(str(value.value))
            else:
                parts.append("{}")
        return "".join(parts)
    if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Add):
        return _template(node.left) + _template(node.right)
    return "{}"  # a message built elsewhere (a variable): matches any catalogue entry's placeholder


def error_sites(paths: list[Path], root: Path) -> list[Site]:
    sites = []
    for path in paths:
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in ast.walk(tree):
            if not isinstance(node, ast.Call):
                continue
            name = node.func.id if isinstance(node.func, ast.Name) else node.func.attr if isinstance(node.func, ast.Attribute) else None
            if name in FIELD_ERRORS:
                keywords = {k.arg: k.value for k in node.keywords}
                problem = node.args[1] if len(node.args) > 1 else keywords.get("problem")
                if problem is not None and _template(problem) != "{}":
                    sites.append(Site(str(path.relative_to(root)), node.lineno, "{} " + _template(problem)))
            elif node.args and (name in ERROR_TYPES or name in MESSAGE_HELPERS):
                template = _template(node.args[0])
                if template != "{}":
                    prefix = MESSAGE_HELPERS.get(name, "")
                    sites.append(Site(str(path.relative_to(root)), node.lineno, prefix + template))
    return sites


def normalise(template: str) -> str:
    """`{file}` and `{}` alike: placeholders compare equal whatever they are called."""
    return re.sub(r"\{[^{}]*\}", "{}", template)


def pattern_regex(template: str) -> re.Pattern:
    """A regex matching messages made from `template` (each placeholder: any text)."""
    parts = re.split(r"\{[^{}]*\}", template)
    return re.compile(".*?".join(re.escape(part) for part in parts), re.DOTALL)
