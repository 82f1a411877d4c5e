"""Errors that reach the user as one line: they name the file or field and say what is wrong."""

from __future__ import annotations


class ImitationError(Exception):
    """A problem with the user's input or environment; the CLI prints it as one line, exit code 1."""


class ConfigError(ImitationError):
    """A setting out of range. Learners speak their own vocabulary: the message names the config
    field (`learning_rate must be …`), and `owner` the config class it belongs to, so that the
    command line can name the flag the user typed instead (`--lr must be …`)."""

    def __init__(self, field: str, problem: str, *, owner: str | None = None) -> None:
        super().__init__(f"{field} {problem}")
        self.field = field
        self.problem = problem
        self.owner = owner

    def renamed(self, name: str) -> str:
        """The message with the field called `name`."""
        return f"{name} {self.problem}"


class DemoFileError(ImitationError):
    """An MCAP demo file that cannot be read as asked: not MCAP, damaged, wrong schema or version."""


class SpaceError(ImitationError):
    """A gymnasium space that cannot be serialised, or data that does not fit its space."""


class WriteError(ImitationError):
    """An operating-system error while writing an output (disk full, read-only, permission)."""
