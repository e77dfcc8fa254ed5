"""Writing a user's output file without ever losing one.

Every command claims all its outputs up front (:func:`claim_outputs`), before any work is done: a name
that is a directory, names the input, is given twice, or is an existing file the user did not ask to
replace (``--force``) is one line, exit 2, and nothing is written — a long diagnosis does not fail at its
end. The content is written to a temporary file next to the target and renamed onto it only once
complete (:func:`replace_when_done`), so a failure half-way (nothing to write, disk full, a bad input
found late, a crash) leaves an old file as it was; without ``--force`` the rename never replaces a file
that appeared meanwhile.
"""

from __future__ import annotations

import contextlib
import os
import secrets
import shutil
import sys
from collections.abc import Iterable, Iterator
from pathlib import Path

from furuta_rt.errors import UserError

Named = tuple[str, "str | Path | None"]
"""(the option that named it, e.g. ``--csv``; the path, or None when the option was not given)."""


def _resolved(p: Path, flag: str) -> Path:
    """``p`` with its symbolic links resolved; a link loop is one line, not a RuntimeError."""
    try:
        return p.resolve()
    except (RuntimeError, OSError):
        raise UserError(f"{flag} {p} is a symbolic link loop (it never reaches a file)") from None


def refusal(flag: str, path: str | Path) -> UserError:
    """The one line that refuses to replace ``path`` (named by ``flag``)."""
    return UserError(f"{flag} {path} already exists; refusing to overwrite it (pass --force to replace it)")


def _special(p: Path) -> bool:
    """An existing name that is neither a regular file nor a directory (a device such as /dev/null or
    /dev/stdout, a FIFO): written into as it is, never refused nor replaced — it holds no file to lose."""
    return p.exists() and not p.is_file() and not p.is_dir()


def refuse_existing(path: str | Path, *, force: bool, flag: str) -> None:
    """UserError if ``path`` is a directory, or an existing file and not ``force`` (``flag``: the option
    that named it, e.g. ``--log``)."""
    p = Path(path)
    if p.is_dir():
        raise UserError(f"{flag} {p} is a directory; give a file name")
    if p.exists() and not force and not _special(p):
        raise refusal(flag, p)


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


def claim_outputs(outputs: Iterable[Named], *, force: bool, inputs: Iterable[str | Path] = ()) -> None:
    """Check every output a command will write, before it does any work: not a directory, not one of
    ``inputs``, not named twice, not an existing file unless ``force``, and writable (nothing is created
    or truncated here). Options that were not given (path None) are skipped."""
    seen: dict[Path, str] = {}
    sources = {_resolved(Path(p), "input") for p in inputs}
    for flag, path in outputs:
        if path is None:
            continue
        p = Path(path)
        key = _resolved(p, flag)
        if key in sources:
            raise UserError(f"{flag} {p} is the input; give another name")
        if key in seen and not _special(p):
            raise UserError(f"{flag} {p} is also given as {seen[key]}; give each output its own name")
        seen[key] = flag
        refuse_existing(p, force=force, flag=flag)
        probe_writable(p, f"{flag}")


def claim_or_exit(prog: str, outputs: Iterable[Named], *, force: bool, inputs: Iterable[str | Path] = ()) -> None:
    """:func:`claim_outputs` for a script or tool outside the ``furuta-rt`` CLI: a refusal is one line
    ``prog: error: …`` on stderr and exit code 2."""
    try:
        claim_outputs(outputs, force=force, inputs=inputs)
    except UserError as err:
        print(f"{prog}: error: {err}", file=sys.stderr)
        raise SystemExit(2) from None


def _new_file_mode(existing: Path) -> int:
    """The mode the finished file gets: the replaced file's, else what a plain open() would give."""
    with contextlib.suppress(OSError):
        return existing.stat().st_mode & 0o7777
    mask = os.umask(0o022)
    os.umask(mask)
    return 0o666 & ~mask


def _move_into_place(tmp: Path, target: Path, *, overwrite: bool, flag: str) -> None:
    """Rename ``tmp`` onto ``target`` in one step; without ``overwrite`` a file at ``target`` (one that
    appeared after the outputs were claimed) is refused, not replaced: a hard link fails when the name
    exists, where a rename would replace it."""
    if overwrite:
        os.replace(tmp, target)
        return
    try:
        os.link(tmp, target)
    except FileExistsError:
        raise refusal(flag, target) from None
    except OSError:  # a file system without hard links: the check and the rename are two steps there
        if target.exists():
            raise refusal(flag, target) from None
        os.replace(tmp, target)
    else:
        tmp.unlink()


@contextlib.contextmanager
def replace_when_done(path: str | Path, *, overwrite: bool = True, flag: str = "output") -> Iterator[Path]:
    """A temporary path next to ``path`` (same extension, so a writer that goes by it picks the format)
    for the block to write; moved onto ``path`` when the block ends normally, removed when it raises
    (``path`` untouched then). Without ``overwrite`` an existing ``path`` is refused (named by ``flag``).
    A symbolic link keeps pointing where it did: the file it names is the one replaced; a device or FIFO
    (/dev/null, /dev/stdout) is written directly."""
    p = Path(path)
    if p.is_symlink():
        p = _resolved(p, flag)
    if _special(p):
        yield p
        return
    mode = _new_file_mode(p)
    tmp = p.with_name(f".{p.stem}.{secrets.token_hex(4)}.partial{p.suffix}")
    try:
        os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))
    except OSError as err:
        raise UserError(f"cannot write {p}: {err.strerror or err}") from None
    try:
        yield tmp
        os.chmod(tmp, mode)
        _move_into_place(tmp, p, overwrite=overwrite, flag=flag)
    finally:
        tmp.unlink(missing_ok=True)


def write_text(path: str | Path, text: str, *, overwrite: bool, flag: str) -> None:
    """``text`` into ``path`` through :func:`replace_when_done` (complete or not at all)."""
    with replace_when_done(path, overwrite=overwrite, flag=flag) as tmp:
        tmp.write_text(text)


def files_in_the_way(directory: str | Path, names: Iterable[str]) -> list[str]:
    """Which of ``names`` already exist in ``directory`` (none when it does not exist)."""
    d = Path(directory)
    return [n for n in names if (d / n).exists()] if d.is_dir() else []


def claim_directory(flag: str, directory: str | Path | None, names: Iterable[str], *, force: bool) -> None:
    """The directory counterpart of :func:`claim_outputs`: not a file, and (unless ``force``) holding
    none of the files ``names`` that will be written into it."""
    if directory is None:
        return
    d = Path(directory)
    if d.exists() and not d.is_dir():
        raise UserError(f"{flag} {d} is a file; give a directory (it is created if missing)")
    anchor = next(p for p in (d, *d.absolute().parents) if p.exists())
    if not anchor.is_dir() or not os.access(anchor, os.W_OK | os.X_OK):
        raise UserError(f"cannot write into {flag} {d}: {anchor} is not a directory we may write")
    in_the_way = files_in_the_way(d, names)
    if in_the_way and not force:
        more = f" and {len(in_the_way) - 1} more" if len(in_the_way) > 1 else ""
        raise UserError(f"{flag} {d} already holds {in_the_way[0]}{more}; refusing to overwrite "
                        "(pass --force to replace them)")


@contextlib.contextmanager
def directory_when_done(directory: str | Path, names: Iterable[str], *, overwrite: bool,
                        flag: str) -> Iterator[Path]:
    """A temporary directory next to ``directory`` for the block to fill; when the block ends normally
    its files go into ``directory`` (created if missing) and the files of ``names`` the block did not
    write again are removed from it (no stale figure beside a new page); when it raises, ``directory``
    is left as it was. Without ``overwrite`` a file of ``names`` already in ``directory`` is refused."""
    d = Path(directory)
    ours = tuple(names)
    whole = Path(os.path.abspath(d))  # '.' and '..' have no name to put beside
    tmp = whole.with_name(f".{whole.name}.{secrets.token_hex(4)}.partial")
    try:
        tmp.parent.mkdir(parents=True, exist_ok=True)
        tmp.mkdir()
    except OSError as err:
        raise UserError(f"cannot write into {flag} {d}: {err.strerror or err}") from None
    try:
        yield tmp
        in_the_way = files_in_the_way(d, ours)
        if in_the_way and not overwrite:
            raise refusal(flag, d / in_the_way[0])
        d.mkdir(exist_ok=True)
        written = sorted(p.name for p in tmp.iterdir())
        strays = [n for n in written if n not in ours and (d / n).exists()]
        if strays:  # a file the caller did not declare: never replaced, even with overwrite
            raise refusal(flag, d / strays[0])
        for name in written:
            os.replace(tmp / name, d / name)
        for name in set(in_the_way) - set(written):
            (d / name).unlink()
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
