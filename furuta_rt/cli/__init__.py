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
import importlib
import sys

from furuta_rt.errors import UserError

COMMANDS = ("analyze", "convert", "design", "diagnose", "repair", "replay", "run")
"""The subcommand modules of this package, in the order ``--help`` lists them."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="furuta-rt",
        description="Real-time control, logging and physics diagnosis for a Furuta pendulum rig.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMANDS:
        importlib.import_module(f"{__name__}.{name}").register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except UserError as err:
        print(f"furuta-rt {args.command}: error: {err}", file=sys.stderr)
        return err.exit_code
    except OSError as err:
        # A file or device the user named cannot be used: say which and why, in one line.
        target = f": {err.filename}" if err.filename else ""
        reason = (err.strerror or str(err)).lower()
        print(f"furuta-rt {args.command}: error: {reason}{target} (check the path and its permissions)", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"furuta-rt {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
