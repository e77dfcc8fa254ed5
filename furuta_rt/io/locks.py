"""The lock on a log while a run writes it (``flock``): another run, ``run --force`` and ``repair`` see it and
refuse that file in one line instead of tearing it. The lock goes with the writer's file descriptor, so a
killed run leaves none behind."""

from __future__ import annotations

import contextlib
import fcntl
import os
from pathlib import Path
from typing import BinaryIO

from furuta_rt.errors import UserError


def _busy(path: Path, what: str) -> UserError:
    return UserError(f"{what} {path} is being written by a running furuta-rt run (it holds the file's lock); "
                     "wait for that run to end, or give another name")


def open_locked_for_writing(path: str | Path, *, exclusive: bool, what: str = "the log") -> BinaryIO:
    """``path`` opened for writing with an exclusive lock held, emptied only once the lock is ours (never a
    file another run is writing); ``exclusive``: the file must not exist yet."""
    p = Path(path)
    flags = os.O_WRONLY | os.O_CREAT | (os.O_EXCL if exclusive else 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(p, flags, 0o644)
    except OSError as err:
        raise UserError(f"cannot write {p}: {err.strerror or err}") from None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        raise _busy(p, what) from None
    os.ftruncate(fd, 0)
    return os.fdopen(fd, "wb")


def refuse_if_being_written(path: str | Path, what: str) -> None:
    """One line (UserError) if a run holds the lock of the existing file ``path``; nothing if it does not exist."""
    p = Path(path)
    try:
        fd = os.open(p, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except OSError:
        return  # absent or unreadable: the caller's own checks say so
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        raise _busy(p, what) from None
    except OSError:
        return
    finally:
        with contextlib.suppress(OSError):
            os.close(fd)
