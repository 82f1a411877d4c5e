"""An AST scan for code that would let a file run code when it is loaded.

Forbidden anywhere in the package and cli.py:

- importing pickle, cPickle, _pickle, dill, joblib, cloudpickle or shelve (pickletools, which
  only disassembles, is allowed);
- `torch.load` (or `torch.serialization.load`) without the literal keyword `weights_only=True`;
- `numpy.load` with `allow_pickle` set to anything but the literal False;
- `yaml.load`/`yaml.load_all` without a safe loader (SafeLoader/CSafeLoader), and
  `yaml.unsafe_load`, `yaml.full_load`, `yaml.full_load_all` (yaml.safe_load is fine);
- `pandas.read_pickle` (any `.read_pickle(...)` call);
- the builtins `eval`, `exec`, `compile` and `__import__` (methods such as `module.eval()` are fine).

Aliases are followed: `import numpy as np; np.load(...)`, `from torch import load as tl; tl(...)`.
"""

from __future__ import annotations

import ast
from dataclasses import dataclass
from pathlib import Path

FORBIDDEN_MODULES = {"pickle", "cPickle", "_pickle", "dill", "joblib", "cloudpickle", "shelve"}
FORBIDDEN_BUILTINS = {"eval", "exec", "compile", "__import__"}
SAFE_YAML_LOADERS = {"SafeLoader", "CSafeLoader"}
UNSAFE_YAML = {"yaml.unsafe_load", "yaml.unsafe_load_all", "yaml.full_load", "yaml.full_load_all"}


@dataclass(frozen=True)
class Finding:
    path: str
    line: int
    what: str

    def __str__(self) -> str:
        return f"{self.path}:{self.line}: {self.what}"


def _dotted(node: ast.AST) -> str | None:
    """`a.b.c` for an attribute chain over a name, else None."""
    parts: list[str] = []
    while isinstance(node, ast.Attribute):
        parts.append(node.attr)
        node = node.value
    if isinstance(node, ast.Name):
        parts.append(node.id)
        return ".".join(reversed(parts))
    return None


def _keyword(call: ast.Call, name: str) -> ast.expr | None:
    return next((k.value for k in call.keywords if k.arg == name), None)


def _is_constant(node: ast.expr | None, value: object) -> bool:
    return isinstance(node, ast.Constant) and node.value is value


class _Scanner(ast.NodeVisitor):
    def __init__(self, path: str) -> None:
        self.path = path
        self.aliases: dict[str, str] = {}  # local name -> fully qualified name
        self.findings: list[Finding] = []

    def _flag(self, node: ast.AST, what: str) -> None:
        self.findings.append(Finding(self.path, getattr(node, "lineno", 0), what))

    def visit_Import(self, node: ast.Import) -> None:
        for alias in node.names:
            if alias.name.split(".")[0] in FORBIDDEN_MODULES:
                self._flag(node, f"import {alias.name}")
            local = alias.asname or alias.name.split(".")[0]
            self.aliases[local] = alias.name if alias.asname else local

    def visit_ImportFrom(self, node: ast.ImportFrom) -> None:
        module = node.module or ""
        if module.split(".")[0] in FORBIDDEN_MODULES:
            self._flag(node, f"from {module} import ...")
        for alias in node.names:
            self.aliases[alias.asname or alias.name] = f"{module}.{alias.name}"

    def _qualified(self, func: ast.expr) -> str | None:
        dotted = _dotted(func)
        if dotted is None:
            return None
        head, _, rest = dotted.partition(".")
        if head in self.aliases:
            return self.aliases[head] + ("." + rest if rest else "")
        return dotted

    def visit_Call(self, node: ast.Call) -> None:
        name = self._qualified(node.func)
        if isinstance(node.func, ast.Name) and node.func.id in FORBIDDEN_BUILTINS and node.func.id not in self.aliases:
            self._flag(node, f"{node.func.id}(...) runs code from data")
        if name in ("torch.load", "torch.serialization.load") and not _is_constant(_keyword(node, "weights_only"), True):
            self._flag(node, f"{name}(...) without weights_only=True unpickles arbitrary objects")
        if name in ("numpy.load", "numpy.lib.npyio.load"):
            allow = _keyword(node, "allow_pickle")
            if allow is not None and not _is_constant(allow, False):
                self._flag(node, f"{name}(...) with allow_pickle unpickles object arrays")
        if name in ("yaml.load", "yaml.load_all"):
            loader = _keyword(node, "Loader") or (node.args[1] if len(node.args) > 1 else None)
            loader_name = _dotted(loader) if loader is not None else None
            if loader_name is None or loader_name.split(".")[-1] not in SAFE_YAML_LOADERS:
                self._flag(node, f"{name}(...) without a SafeLoader can build arbitrary objects")
        if name in UNSAFE_YAML:
            self._flag(node, f"{name}(...) can build arbitrary objects")
        if isinstance(node.func, ast.Attribute) and node.func.attr == "read_pickle":
            self._flag(node, "read_pickle(...) unpickles")
        self.generic_visit(node)


def scan_source(source: str, path: str = "<source>") -> list[Finding]:
    scanner = _Scanner(path)
    scanner.visit(ast.parse(source, filename=path))
    return scanner.findings


def scan_files(paths: list[Path]) -> list[Finding]:
    findings: list[Finding] = []
    for path in paths:
        findings += scan_source(path.read_text(encoding="utf-8"), str(path))
    return findings
