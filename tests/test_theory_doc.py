"""docs/THEORY.md: every code path it cites still resolves, its sections are numbered so that
docstrings can cite them, and it stands on its own (a clone of the repository has nothing else)."""

from __future__ import annotations

import importlib
import re
from pathlib import Path

THEORY = Path(__file__).resolve().parents[1] / "docs" / "THEORY.md"

_FENCED = re.compile(r"^(```|~~~)[^\n]*\n.*?^\1[ \t]*$", re.DOTALL | re.MULTILINE)
_CODE_SPAN = re.compile(r"`([^`]+)`")  # a span may wrap onto the next line
_DOTTED = re.compile(r"imitation(?:\.[A-Za-z_][A-Za-z0-9_]*)+")
_SECTION = re.compile(r"^## (\d+) \S", re.MULTILINE)
_SUBSECTION = re.compile(r"^### (\d+)\.(\d+) \S", re.MULTILINE)
_NOT_YET = "Implemented: not yet (planned)."


def _text() -> str:
    return THEORY.read_text(encoding="utf-8")


def cited_paths(text: str) -> list[str]:
    """Every dotted path that a backticked span starts with `imitation.`, e.g. `imitation.algorithms.ppo.compute_gae`
    (text after the path, such as a call's arguments, is ignored). Fenced code blocks are skipped."""
    paths = set()
    for span in _CODE_SPAN.findall(_FENCED.sub("", text)):
        match = _DOTTED.match(span.strip())
        if match and span.strip().startswith("imitation."):
            paths.add(match.group(0))
    return sorted(paths)


def resolve(path: str) -> object:
    """Import the longest importable module prefix of `path`, then getattr the rest, attribute by
    attribute. Raises what went wrong (ImportError, AttributeError, or an error raised on import)."""
    parts = path.split(".")
    for split in range(len(parts), 0, -1):
        name = ".".join(parts[:split])
        try:
            found: object = importlib.import_module(name)
        except ModuleNotFoundError as error:
            # Only "this very module does not exist" means: try a shorter prefix. A module that
            # exists but fails to import (a missing dependency, a broken import) is an error.
            if error.name is not None and (name == error.name or name.startswith(error.name + ".")):
                continue
            raise
        for depth in range(split, len(parts)):
            try:
                found = getattr(found, parts[depth])
            except AttributeError:
                raise AttributeError(f"{'.'.join(parts[:depth])} has no attribute {parts[depth]!r}") from None
        return found
    raise ImportError(f"no prefix of {path} is an importable module")


def test_every_cited_code_path_resolves() -> None:
    paths = cited_paths(_text())
    assert len(paths) >= 30, f"only {len(paths)} backticked imitation.* paths found in {THEORY.name}: is the parser broken?"
    broken = []
    for path in paths:
        try:
            resolve(path)
        except Exception as error:  # noqa: BLE001 - every failure is reported, not just the first
            broken.append(f"{path}  ({type(error).__name__}: {error})")
    assert not broken, f"{len(broken)} of {len(paths)} code paths cited in docs/THEORY.md do not resolve:\n" + "\n".join(broken)


def test_the_document_stands_on_its_own() -> None:
    text = _text()
    for forbidden in ("../shared", "shared/theory", "notes §"):
        assert forbidden not in text, f"docs/THEORY.md refers to {forbidden!r}, which a clone of the repository does not have"


def test_sections_are_numbered_and_say_where_they_are_implemented() -> None:
    text = _text()
    sections = [int(number) for number in _SECTION.findall(text)]
    assert sections == list(range(sections[0], sections[0] + len(sections))), f"top-level sections out of sequence: {sections}"
    headings = list(_SUBSECTION.finditer(text))
    numbers = [(int(match.group(1)), int(match.group(2))) for match in headings]
    assert len(set(numbers)) == len(numbers), "a subsection number is used twice"
    problems = []
    for index, match in enumerate(headings):
        section, subsection = numbers[index]
        # The subsection's body runs to the next heading of either level.
        following = re.search(r"^##", text[match.end() :], re.MULTILINE)
        body = text[match.end() : match.end() + following.start()] if following else text[match.end() :]
        parent = [int(n) for n in _SECTION.findall(text[: match.start()])]
        if not parent or parent[-1] != section:
            problems.append(f"§{section}.{subsection} is not under a heading '## {section} …'")
        if subsection != (1 if index == 0 or numbers[index - 1][0] != section else numbers[index - 1][1] + 1):
            problems.append(f"§{section}.{subsection} is out of sequence")
        if not re.search(r"^Implemented: ", body, re.MULTILINE):
            problems.append(f"§{section}.{subsection} has no 'Implemented:' line")
        if _NOT_YET in body and cited_paths(body):
            problems.append(f"§{section}.{subsection} is marked not yet implemented but cites {cited_paths(body)}")
    assert not problems, "\n".join(problems)
