"""Opening a user's input files without waiting or reading for ever: a FIFO blocks `open()`
until a writer comes, and a device (`/dev/zero`, `/dev/urandom`) never ends. Every reader opens
its input through `open_input` (or checks a path it hands to a library with `check_input`),
which refuses anything but a regular file in one line before a byte is read. A folder is
reported as `open()` reports it (IsADirectoryError), so each reader keeps its own message for it.
"""

from __future__ import annotations

import errno
import os
import stat
from typing import BinaryIO

from imitation.errors import ImitationError
from imitation.output import kind_of_mode


def open_input_fd(path: str | os.PathLike) -> int:
    """A descriptor of the regular file at `path`, opened for reading."""
    # O_NONBLOCK: a FIFO without a writer opens at once instead of waiting for one.
    fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC | os.O_NONBLOCK)
    try:
        mode = os.fstat(fd).st_mode
        if stat.S_ISDIR(mode):
            raise IsADirectoryError(errno.EISDIR, os.strerror(errno.EISDIR), os.fspath(path))
        if not stat.S_ISREG(mode):
            raise ImitationError(f"{os.fspath(path)}: is {kind_of_mode(mode)}, not a regular file; give a file")
        os.set_blocking(fd, True)
    except BaseException:
        os.close(fd)
        raise
    return fd


def open_input(path: str | os.PathLike) -> BinaryIO:
    """The regular file at `path`, opened for reading in binary."""
    return os.fdopen(open_input_fd(path), "rb")


def check_input(path: str | os.PathLike) -> None:
    """Refuse a FIFO, socket or device at `path` before a library opens it; a folder or a
    missing path is left to the caller."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return
    if not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):
        raise ImitationError(f"{os.fspath(path)}: is {kind_of_mode(mode)}, not a regular file; give a file")
