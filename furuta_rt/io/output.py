"""Writing a user's output file without ever losing one.

An existing file is replaced only when the user asked for it (``--force``), and only once the new
content is complete: it is written to a temporary file next to the target and renamed over it, so a
failure half-way (nothing to write, disk full, a bad input found late) leaves the old file as it was.
"""

from __future__ import annotations

import contextlib
import os
import secrets
from collections.abc import Iterator
from pathlib import Path

from furuta_rt.errors import UserError


def refuse_existing(path: str | Path, *, force: bool, flag: str) -> None:
    """UserError if ``path`` is a directory, or an existing file and not ``force`` (``flag``: the option
    that named it, e.g. ``--log``)."""
    p = Path(path)
    if p.is_dir():
        raise UserError(f"{flag} {p} is a directory; give a file name")
    if p.exists() and not force:
        raise UserError(f"{flag} {p} already exists; give another name, or add --force to replace it")


def probe_writable(path: str | Path, what: str) -> None:
    """UserError (naming ``what`` and ``path``) unless ``path`` can be written; changes nothing: an
    existing file is opened without truncating it, a new one is created and removed again."""
    p = Path(path)
    try:
        if p.exists():
            with p.open("r+b"):
                pass
        else:
            with p.open("xb"):
                pass
            p.unlink()
    except OSError as err:
        raise UserError(f"cannot write {what} {p}: {err.strerror or err}") from None


def _new_file_mode(existing: Path) -> int:
    """The mode the finished file gets: the replaced file's, else what a plain open() would give."""
    with contextlib.suppress(OSError):
        return existing.stat().st_mode & 0o7777
    mask = os.umask(0o022)
    os.umask(mask)
    return 0o666 & ~mask


@contextlib.contextmanager
def replace_when_done(path: str | Path) -> Iterator[Path]:
    """A temporary path next to ``path`` (same extension) for the block to write; renamed onto ``path``
    when the block ends normally, removed when it raises (``path`` untouched then)."""
    p = Path(path)
    mode = _new_file_mode(p)
    tmp = p.with_name(f".{p.stem}.{secrets.token_hex(4)}.partial{p.suffix}")
    try:
        os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))
    except OSError as err:
        raise UserError(f"cannot write {p}: {err.strerror or err}") from None
    try:
        yield tmp
        os.chmod(tmp, mode)
        os.replace(tmp, p)
    finally:
        tmp.unlink(missing_ok=True)
