"""The import-layer contract: data flows one way. Every import in the package, lazy ones inside
functions and TYPE_CHECKING ones included, goes down the layers, never up:

    base (errors, limits, output, seeding, checkpoints, runs, bundled, flags)
      → envs → data → models (policies, rewards, observation_encoding, mlp) → experts → learners (algorithms)
      → evaluation → jobs → cli

so data never imports learners or jobs, learners never import evaluation, jobs or the CLI,
models never import learners, and evaluation never imports jobs. The check is an AST scan; the
second test shows it fails when a forbidden import is added."""

from __future__ import annotations

import ast
from pathlib import Path

from support import REPO

ORDER = ["base", "envs", "data", "models", "experts", "learners", "evaluation", "jobs", "cli"]
PREFIXES = {
    "imitation.envs": "envs",
    "imitation.data": "data",
    "imitation.policies": "models",
    "imitation.policy_protocol": "models",
    "imitation.policy_kinds": "models",
    "imitation.chunk_policy": "models",
    "imitation.diffusion_policy": "models",
    "imitation.sequence_policy": "models",
    "imitation.rewards": "models",
    "imitation.observation_encoding": "models",  # how observations enter policies and reward models
    "imitation.mlp": "models",
    "imitation.experts": "experts",
    "imitation.algorithms": "learners",
    "imitation.evaluation": "evaluation",
    "imitation.jobs": "jobs",
    "cli": "cli",
    "imitation.commands": "cli",  # the command line's declarations, read by cli.py
    "imitation.train_commands": "cli",  # the train commands' table: declarations and how each runs its learner
    "imitation.__main__": "cli",  # the entry point: `python -m imitation` runs the command line
}


def layer(module: str) -> str | None:
    """The layer of a module of this project (None for third-party modules)."""
    for prefix, name in PREFIXES.items():
        if module == prefix or module.startswith(prefix + "."):
            return name
    return "base" if module == "imitation" or module.startswith("imitation.") else None


def module_name(path: Path, root: Path) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imported(tree: ast.AST, module: str) -> list[tuple[int, str]]:
    """(line, module) of every import in the tree, relative ones resolved against `module`."""
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".")[: -node.level]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            found.append((node.lineno, target))
            # `from imitation import jobs` imports the subpackage itself
            found += [
                (node.lineno, f"{target}.{alias.name}")
                for alias in node.names
                if layer(f"{target}.{alias.name}") != layer(target)
            ]
    return found


def violations(root: Path) -> list[str]:
    """Every import of a higher layer, as 'file:line: module (layer) imports name (layer)'."""
    paths = sorted((root / "imitation").rglob("*.py")) + [path for path in [root / "cli.py"] if path.is_file()]
    problems = []
    for path in paths:
        module = module_name(path, root)
        own = layer(module)
        for line, name in imported(ast.parse(path.read_text(), filename=str(path)), module):
            other = layer(name)
            if other is not None and ORDER.index(other) > ORDER.index(own):
                problems.append(f"{path.relative_to(root)}:{line}: {module} ({own}) imports {name} ({other})")
    return problems


def test_every_import_goes_down_the_layers() -> None:
    problems = violations(REPO)
    assert not problems, "imports against the layers:\n" + "\n".join(problems)


def test_the_check_fails_when_a_forbidden_import_is_added(tmp_path: Path) -> None:
    forbidden = {
        "imitation/data/reader.py": "from imitation.algorithms.bc import BCConfig\n",  # data imports a learner
        "imitation/data/writer.py": "def f():\n    import imitation.jobs.loop\n",  # data imports the job layer, lazily
        "imitation/algorithms/ppo.py": "from imitation.evaluation.policy import evaluate_policy\n",  # a learner imports evaluation
        "imitation/algorithms/bc.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    import cli\n",  # a learner imports the CLI
        "imitation/rewards.py": "from imitation.algorithms import gcl\n",  # a model imports a learner
        "imitation/evaluation/reward.py": "from ..jobs.ppo import ppo_job\n",  # evaluation imports jobs (relative)
    }
    for name, source in forbidden.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(source)
    (tmp_path / "imitation/jobs").mkdir()
    (tmp_path / "imitation/jobs/bc.py").write_text("from imitation.algorithms.bc import BCConfig\nimport numpy\n")  # allowed
    found = violations(tmp_path)
    assert len(found) == len(forbidden), found
    for name in forbidden:
        assert any(problem.startswith(name + ":") for problem in found), (name, found)
