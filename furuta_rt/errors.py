"""User-facing errors: one line naming the problem and the fix, exit code 2, no traceback."""

from __future__ import annotations


class UserError(Exception):
    """Bad input from the user (configuration, files, devices). ``str(err)`` is the whole message."""

    exit_code = 2
