"""Writing outputs without losing or damaging anything: every writer (demo files, run
directories, exports, reports) goes through this module.

- A target must be a regular file (a directory for runs) or a new path: a symlink, FIFO or
  device named by `--out` is refused rather than followed or replaced.
- Temporaries are created exclusively (`O_CREAT | O_EXCL | O_NOFOLLOW`), so a planted symlink at
  a predictable `.partial` name makes the write fail instead of redirecting it.
- `OutputLock` is an advisory `flock` on a lock file beside the target, held for the whole
  write: a second writer to the same target fails at once, naming the holder's pid. A lock
  file that is a hard link (or not a regular file) is refused, never written through.
- A finished run directory replaces the old one with one `renameat2(RENAME_EXCHANGE)`, so there
  is no moment at which neither exists.
- `OSError`s become one line naming the path and the cause (disk full, read-only, ...).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import errno
import fcntl
import os
import re
import shutil
import stat
import time
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import Any, BinaryIO

from imitation.errors import ImitationError, WriteError

_CAUSES = {
    errno.ENOSPC: "no space left on the device (disk full)",
    errno.EDQUOT: "disk quota exceeded",
    errno.EFBIG: "file too large for this file system or limit",
    errno.EROFS: "read-only file system",
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
    errno.EILSEQ: "the name is not valid on this file system",
    errno.ENAMETOOLONG: "the name is too long",
    errno.ELOOP: "is a symbolic link (not followed)",
}


def os_error(path: str | os.PathLike, error: OSError, doing: str = "cannot write") -> WriteError:
    """The one-line error for an OSError while writing `path`."""
    cause = _CAUSES.get(error.errno) if error.errno is not None else None
    return WriteError(f"{_printable(path)}: {doing}: {cause or error.strerror or error}")


@contextmanager
def writing(path: str | os.PathLike) -> Iterator[None]:
    """Within the block, an OSError (or a safetensors I/O error, which carries the OS error
    number in its text) becomes `os_error(path, ...)`."""
    try:
        yield
    except OSError as error:
        raise os_error(error.filename or path, error) from None
    except Exception as error:
        found = re.search(r"\(os error (\d+)\)", str(error))
        if found is None or type(error).__name__ != "SafetensorError":
            raise
        number = int(found.group(1))
        raise os_error(path, OSError(number, os.strerror(number))) from None


def _printable(path: str | os.PathLike) -> str:
    """A path as text even when its bytes are not valid UTF-8 (shown escaped)."""
    return os.fsencode(path).decode("utf-8", "backslashreplace")


def kind_of_mode(mode: int) -> str:
    if stat.S_ISLNK(mode):
        return "a symbolic link"
    if stat.S_ISDIR(mode):
        return "a directory"
    if stat.S_ISFIFO(mode):
        return "a FIFO"
    if stat.S_ISCHR(mode):
        return "a character device"
    if stat.S_ISBLK(mode):
        return "a block device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "a regular file"


def check_target(path: str | os.PathLike, *, directory: bool = False, flag: str = "--out") -> None:
    """Refuse a target that exists and is not a regular file (a real directory when
    `directory`): writing would follow a symlink or replace a special file."""
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return
    except OSError as error:
        raise os_error(path, error, "cannot inspect") from None
    wanted = stat.S_ISDIR(mode) if directory else stat.S_ISREG(mode)
    if not wanted:
        needed = "a directory" if directory else "a regular file"
        raise ImitationError(
            f"{flag} {_printable(path)}: is {kind_of_mode(mode)}; it must be {needed} or a new path (remove it, or choose "
            "another name)"
        )


def create_exclusive(path: str | os.PathLike, *, target: str | os.PathLike | None = None) -> BinaryIO:
    """Open a new file for writing; fail if anything (a file, a symlink) is already there.
    An OSError names `target` (what the user asked for), the temporary name otherwise."""
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC, 0o666)
    except FileExistsError:
        raise ImitationError(
            f"{_printable(path)}: exists; it was not made by this run (remove it, or choose another name)"
        ) from None
    except OSError as error:
        raise os_error(target if target is not None else path, error) from None
    return os.fdopen(fd, "wb")


def umask() -> int:
    """The process's umask, read without changing it (os.umask sets it, racing other threads)."""
    try:
        with open("/proc/self/status") as status:
            for line in status:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    previous = os.umask(0o022)
    os.umask(previous)
    return previous


def as_the_umask_allows(path: str | os.PathLike) -> None:
    """Give a finished output, and each file and folder inside it, the permissions the user's
    umask allows a new one: libraries write some results (safetensors' weights, lerobot's
    concatenated videos) through private temporaries, readable by their owner only."""
    mask, root = umask(), Path(path)
    for each in [root, *root.rglob("*")] if root.is_dir() else [root]:
        if not each.is_symlink():
            executable = each.is_dir() or each.stat().st_mode & 0o111
            os.chmod(each, (0o777 if executable else 0o666) & ~mask)


def lstat_kind(path: str | os.PathLike) -> str | None:
    """What is at `path` without following a symlink ("a regular file", "a symbolic link", ...),
    or None when nothing is."""
    try:
        return kind_of_mode(os.lstat(path).st_mode)
    except FileNotFoundError:
        return None


class OutputLock:
    """An exclusive advisory lock on writing `target`, held in `.<name>.lock` beside it.

    Acquiring never waits: if another process holds it, ImitationError names that process. The
    lock file is removed on release; a process that locked a file already unlinked by its
    holder retries on the new one (the inode check), so two writers never both hold it."""

    def __init__(self, target: str | os.PathLike) -> None:
        target = Path(target)
        self.target = target
        self.path = target.with_name(f".{target.name}.lock")
        self._fd: int | None = None

    def acquire(self) -> OutputLock:
        while True:
            try:
                fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC, 0o666)
            except OSError as error:
                raise os_error(self.target, error) from None
            if not _is_own_lock(fd):
                os.close(fd)
                raise ImitationError(
                    f"{_printable(self.path)}: not a lock file of this program (a hard link to another file, or not a regular "
                    "file); not writing through it (remove it)"
                )
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = _read_holder(fd)
                os.close(fd)
                raise ImitationError(
                    f"{_printable(self.target)}: another process {holder}is writing it (lock {_printable(self.path)}); "
                    "wait for it to finish, or choose another output"
                ) from None
            try:
                same = os.fstat(fd).st_ino == os.stat(self.path, follow_symlinks=False).st_ino
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()} {time.strftime('%Y-%m-%dT%H:%M:%S')}\n".encode())
        self._fd = fd
        return self

    def release(self) -> None:
        if self._fd is None:
            return
        with suppress(FileNotFoundError):
            os.unlink(self.path)
        os.close(self._fd)
        self._fd = None

    def __enter__(self) -> OutputLock:
        return self.acquire()

    def __exit__(self, *exc_info: Any) -> None:
        self.release()


def _is_own_lock(fd: int) -> bool:
    """Whether the open lock file is one a writer made: a regular file of one name. A lock file
    is truncated and written (its holder's pid); a planted hard link would make that write land
    in the file it links to."""
    status = os.fstat(fd)
    return stat.S_ISREG(status.st_mode) and status.st_nlink == 1


def remove_stale_locks(folder: Path) -> None:
    """Remove the lock files under `folder` that no process holds: those of writers that were
    killed, left in a run directory that is being continued."""
    for path in folder.rglob(".*.lock"):
        try:
            fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
        except OSError:
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            if _is_own_lock(fd):
                os.unlink(path)
        except OSError:  # held by a live writer, or gone
            pass
        finally:
            os.close(fd)


def _read_holder(fd: int) -> str:
    try:
        text = os.pread(fd, 100, 0).decode("ascii", "replace").split()
    except OSError:
        return ""
    return f"(pid {text[0]}, since {text[1]}) " if len(text) >= 2 else ""


_RENAME_EXCHANGE = 2
_AT_FDCWD = -100


def _renameat2() -> Any:
    libc = ctypes.CDLL(ctypes.util.find_library("c") or None, use_errno=True)
    function = getattr(libc, "renameat2", None)
    if function is not None:
        function.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    return function


def replace_directory(new: Path, target: Path) -> None:
    """Put directory `new` at `target`, replacing the directory there if any.

    An existing target is exchanged with `new` in one step (Linux's renameat2), then the old
    content (now at `new`'s name) is removed; where the call is missing, the old target is first
    moved to `target.old`."""
    if not os.path.lexists(target):
        os.replace(new, target)
        return
    function = _renameat2()
    if function is not None and function(_AT_FDCWD, os.fsencode(new), _AT_FDCWD, os.fsencode(target), _RENAME_EXCHANGE) == 0:
        shutil.rmtree(new, ignore_errors=True)
        return
    if function is not None and ctypes.get_errno() not in (errno.ENOSYS, errno.EINVAL):
        error = ctypes.get_errno()
        raise OSError(error, os.strerror(error), str(target))
    old = target.with_name(target.name + ".old")
    shutil.rmtree(old, ignore_errors=True)
    os.replace(target, old)
    os.replace(new, target)
    shutil.rmtree(old, ignore_errors=True)
