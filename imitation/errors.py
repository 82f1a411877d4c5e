"""Errors that reach the user as one line: they name the file or field and say what is wrong."""


class ImitationError(Exception):
    """A problem with the user's input or environment; the CLI prints it as one line, exit code 1."""


class DemoFileError(ImitationError):
    """An MCAP demo file that cannot be read as asked: not MCAP, damaged, wrong schema or version."""


class SpaceError(ImitationError):
    """A gymnasium space that cannot be serialised, or data that does not fit its space."""


class WriteError(ImitationError):
    """An operating-system error while writing an output (disk full, read-only, permission)."""
