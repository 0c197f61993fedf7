"""Reading untrusted input files safely, written once for every loader: only regular files are
opened, never a FIFO (it would block) or a device such as /dev/zero (it never ends); the size
bound is checked before reading; the opened descriptor is checked again, so a file swapped in
between is refused. Loaders turn the one-line reason into their own error type."""

from __future__ import annotations

import os
import stat
from pathlib import Path


class UnreadableFile(Exception):
    """Why a file was refused: ``reason`` is one line without the path; ``missing`` is True
    when there is no such file."""

    def __init__(self, reason: str, missing: bool = False) -> None:
        super().__init__(reason)
        self.reason = reason
        self.missing = missing


def describe_mode(mode: int) -> str:
    """What a non-regular file is, in words."""
    for test, name in ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISSOCK, "a socket"), (stat.S_ISLNK, "a symbolic link")):
        if test(mode):
            return name
    return "a special file"


def os_reason(exc: BaseException) -> str:
    """One line saying why an ``os`` call on a path failed."""
    if isinstance(exc, FileNotFoundError):
        return "file not found"
    if isinstance(exc, NotADirectoryError):
        return "file not found (a parent in the path is not a folder)"
    if isinstance(exc, PermissionError):
        return "permission denied"
    if isinstance(exc, ValueError):  # a NUL byte in the path
        return "invalid path (NUL byte)"
    return f"cannot read it ({getattr(exc, 'strerror', None) or type(exc).__name__})"


def _os_reason(exc: BaseException) -> UnreadableFile:
    missing = isinstance(exc, (FileNotFoundError, NotADirectoryError))
    return UnreadableFile(os_reason(exc), missing=missing)


def stat_regular(path: str | Path, limit: int, what: str = "this file",
                 follow_symlinks: bool = True) -> os.stat_result:
    """``stat`` without opening: the file must exist, be regular and be at most ``limit``
    bytes.

    Raises
    ------
    UnreadableFile
        With the reason (missing, a folder, a FIFO/device/socket, too large).
    """
    try:
        st = os.stat(path) if follow_symlinks else os.lstat(path)
    except (OSError, ValueError) as exc:
        raise _os_reason(exc) from None
    if stat.S_ISDIR(st.st_mode):
        raise UnreadableFile(f"is a folder, expected {what}")
    if not stat.S_ISREG(st.st_mode):
        raise UnreadableFile(f"is {describe_mode(st.st_mode)}, not a regular file: refused "
                             "without opening it")
    if st.st_size > limit:
        raise UnreadableFile(f"file is {st.st_size} bytes, more than the {limit}-byte limit "
                             f"for {what}: refused without reading it")
    return st


def read_regular(path: str | Path, limit: int, what: str = "this file",
                 follow_symlinks: bool = True) -> bytes:
    """All bytes of the regular file ``path`` (at most ``limit``); see :func:`stat_regular`.
    With ``follow_symlinks=False`` a symbolic link is refused even if one appears after the
    check.

    Raises
    ------
    UnreadableFile
        With the reason.
    """
    before = stat_regular(path, limit, what, follow_symlinks)
    flags = (os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOCTTY", 0)
             | getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_BINARY", 0)
             | (0 if follow_symlinks else getattr(os, "O_NOFOLLOW", 0)))
    try:
        fd = os.open(path, flags)
    except (OSError, ValueError) as exc:
        raise _os_reason(exc) from None
    try:
        now = os.fstat(fd)
        if not stat.S_ISREG(now.st_mode) or (now.st_dev, now.st_ino) != (before.st_dev,
                                                                          before.st_ino):
            raise UnreadableFile("the file changed while it was being opened; refused")
        chunks, size = [], 0
        while size <= limit:
            chunk = os.read(fd, min(1 << 22, limit + 1 - size))
            if not chunk:
                break
            chunks.append(chunk)
            size += len(chunk)
    except OSError as exc:
        raise _os_reason(exc) from None
    finally:
        os.close(fd)
    if size > limit:
        raise UnreadableFile(f"file grew beyond the {limit}-byte limit for {what} while it was "
                             "read")
    return b"".join(chunks)


class DuplicateKey(Exception):
    """A JSON object names one key twice (``json`` would keep the last one silently)."""


def no_duplicate_keys(pairs: list[tuple[str, object]]) -> dict:
    """``object_pairs_hook`` for :func:`json.loads` that refuses duplicated keys."""
    out: dict = {}
    for key, value in pairs:
        if key in out:
            raise DuplicateKey(key)
        out[key] = value
    return out
