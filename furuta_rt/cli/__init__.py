"""`furuta-rt` command line. Each subcommand lives in its own module in this package and exposes
``register(subparsers)``; ``COMMANDS`` lists them (add a module and its name there to add a command).
They are listed, not discovered by reading the package directory: a user who may import the modules
but not list the directory (a clone in a private directory, a dropped-privilege process) would
otherwise get a CLI without commands.

Errors the user can fix (bad config, missing device, bad file) end as one line on stderr and exit
code 2 — never a traceback.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import signal
import sys

from furuta_rt.errors import OneLineParser, UserError
from furuta_rt.runtime import signals as stop_signals

COMMANDS = ("analyze", "convert", "design", "diagnose", "experiment", "repair", "replay", "run")
"""The subcommand modules of this package, in the order ``--help`` lists them."""


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser of every command, or of ``command`` alone (one of COMMANDS): a command's run then imports its
    own module only, not the others' libraries (rich, the replay's plotting, the diagnosis) — in ``run``'s case
    the real-time process, which mlockall then holds in memory."""
    parser = OneLineParser(
        prog="furuta-rt",
        description="Real-time control, logging and physics diagnosis for a Furuta pendulum rig.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in (command,) if command in COMMANDS else COMMANDS:
        importlib.import_module(f"{__name__}.{name}").register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    command = "furuta-rt"
    words = sys.argv[1:] if argv is None else argv
    if words and words[0] == "run":  # the real-time process: before the imports
        from furuta_rt.runtime.rt import lean_process

        lean_process()
    try:
        parser = _build_parser_uninterrupted(words[0] if words else None)
        args, extra = parser.parse_known_args(argv)
        if extra:  # blamed on the command that was given them, not on furuta-rt
            commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
            commands.choices[args.command].error(f"unrecognized arguments: {' '.join(extra)}")
        command = f"furuta-rt {args.command}"
        if argv is None:  # SIGTERM, SIGHUP, SIGQUIT end a command as Ctrl-C does: its cleanup runs (no .partial left)
            stop_signals.install(_interrupt)
        return int(args.func(args) or 0)
    except UserError as err:
        print(f"{command}: error: {err}", file=sys.stderr)
        return err.exit_code
    except BrokenPipeError:  # the reader of our output went away (``| head``): nothing more to say to it
        _silence_stdout()
        return 0
    except OSError as err:
        # A file or device the user named cannot be used: say which and why, in one line.
        target = f": {err.filename}" if err.filename else ""
        reason = (err.strerror or str(err)).lower()
        print(f"{command}: error: {reason}{target} (check the path and its permissions)", file=sys.stderr)
        return 2
    except RuntimeError as err:  # pathlib's resolve() on a symbolic-link loop, wherever a path is resolved
        if not str(err).startswith("Symlink loop from "):
            raise
        print(f"{command}: error: {str(err)[len('Symlink loop from '):]} is a symbolic link loop (it never reaches a file)",
              file=sys.stderr)
        return 2
    except KeyboardInterrupt as err:  # a stop signal before the command could handle it (start-up)
        name = err.args[0] if err.args and isinstance(err.args[0], str) else "SIGINT"
        with contextlib.suppress(OSError):
            print(f"{command}: interrupted ({name})", file=sys.stderr)
        return int(getattr(err, "exit_code", 130))
    finally:
        if argv is None:  # the process's own command line: a late Ctrl-C must not interrupt the interpreter's exit
            _ignore_stop_signals()


def _build_parser_uninterrupted(command: str | None) -> argparse.ArgumentParser:
    """``build_parser`` (it imports every command module) with the stop signals held until it returns: an
    interrupt inside an import can surface as some other error (numpy turns it into an ImportError), so it
    is taken after the imports, as ``KeyboardInterrupt`` (exit 128 + signum)."""
    held: list[int] = []
    names = ("SIGINT", "SIGTERM", "SIGHUP", "SIGQUIT")
    try:
        old = {getattr(signal, n): signal.signal(getattr(signal, n), lambda signum, _f: held.append(signum)) for n in names}
    except ValueError:  # not the main thread: nothing to hold
        return build_parser(command)
    try:
        parser = build_parser(command)
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)
    if held:
        err = KeyboardInterrupt(signal.Signals(held[0]).name)
        err.exit_code = 128 + held[0]  # type: ignore[attr-defined]
        raise err
    return parser


def _interrupt(signum: int, _frame: object) -> None:
    raise stop_signals.Interrupted(signum)


def _silence_stdout() -> None:
    """Later writes to a closed stdout (the interpreter flushes it at exit) must not print a traceback."""
    with contextlib.suppress(OSError, ValueError):
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())


def _ignore_stop_signals() -> None:
    for name in ("SIGINT", "SIGTERM", "SIGHUP", "SIGQUIT"):
        signal.signal(getattr(signal, name), signal.SIG_IGN)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
