"""User-facing errors: one line naming the problem and the fix, exit code 2, no traceback."""

from __future__ import annotations

import argparse
import difflib
from typing import NoReturn


class UserError(Exception):
    """Bad input from the user (configuration, files, devices). ``str(err)`` is the whole message."""

    exit_code = 2


class OneLineParser(argparse.ArgumentParser):
    """A parser whose usage errors are one line naming the command and the option (``--help`` has the usage), with
    the nearest option when one was misspelt; the subcommands' parsers are of this class too."""

    def error(self, message: str) -> NoReturn:
        hint = ""
        if message.startswith("unrecognized arguments:"):
            known = [s for a in self._actions for s in a.option_strings if s.startswith("--")]
            unknown = [w.split("=")[0] for w in message.split(":", 1)[1].split() if w.startswith("-")]
            near = [m for w in unknown for m in difflib.get_close_matches(w, known, n=1, cutoff=0.6)]
            hint = f"; did you mean {' or '.join(near)}?" if near else ""
        self.exit(2, f"{self.prog}: error: {message}{hint} (see {self.prog} --help)\n")
