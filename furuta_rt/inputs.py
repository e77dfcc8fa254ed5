"""Input files checked by what they are before anything reads them: a regular file (through any symbolic
links), not a FIFO that would block forever, not a device such as /dev/zero that never ends, not a
symbolic-link loop. One line naming the file and what it is instead (UserError, exit 2)."""

from __future__ import annotations

import errno
import os
import stat
from pathlib import Path

from furuta_rt.errors import UserError

_KINDS = ((stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISCHR, "a character device"),
          (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))


def regular_input(path: str | Path, what: str) -> Path:
    """``path`` resolved to the regular file it names; UserError (one line) for anything else."""
    p = Path(path)
    try:
        st = os.stat(p)
    except OSError as err:
        if err.errno == errno.ELOOP:
            raise UserError(f"{what} {p} is a symbolic link loop (it never reaches a file)") from None
        if err.errno == errno.ENOENT and os.path.islink(p):
            raise UserError(f"{what} {p} is a symbolic link to {os.readlink(p)}, which does not exist") from None
        if err.errno == errno.ENOENT:
            raise UserError(f"{what} {p} does not exist") from None
        raise UserError(f"cannot read {what} {p}: {(err.strerror or str(err)).lower()}") from None
    if stat.S_ISDIR(st.st_mode):
        raise UserError(f"{what} {p} is a directory; give a file")
    for test, kind in _KINDS:
        if test(st.st_mode):
            raise UserError(f"{what} {p} is {kind}, not a regular file; save it to a file first")
    return Path(os.path.realpath(p))


def read_bounded(path: str | Path, limit: int, what: str) -> bytes:
    """The whole file, refused in one line if it holds more than ``limit`` bytes (never read past that)."""
    with open(path, "rb") as fh:
        data = fh.read(limit + 1)
    if len(data) > limit:
        raise UserError(f"{what} {path} is larger than {limit // (1024 * 1024)} MiB; it is not such a file")
    return data
