"""The signals that end a run, and what each part of a run does with them.

An operator ends a run with Ctrl-C (SIGINT), Ctrl-\\ (SIGQUIT), ``kill`` (SIGTERM) or by closing the
terminal or losing the ssh session (SIGHUP). Each is the same request: stop. While the loop runs it
is an operator stop (u = 0 the device accepts and STOP first, then the log's footer, the summary,
exit 0); before the loop runs it interrupts the start-up (exit 128 + the signal's number, after the
same cleanup); once the run is shutting down, further signals are noted and ignored so the log and the
summary are finished. The logger and dashboard processes ignore them all: the daemon tells them when.
"""

from __future__ import annotations

import signal
from collections.abc import Callable
from typing import Any

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT)
"""Every signal a user or a terminal sends to end a run."""


class Interrupted(KeyboardInterrupt):
    """A stop signal arrived before the loop ran; the exit code is 128 + its number, as a shell reports it."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum

    @property
    def exit_code(self) -> int:
        return 128 + self.signum


def install(handler: Callable[[int, Any], None] | int) -> dict[int, Any]:
    """Give every stop signal ``handler``; returns the previous handlers (for ``restore``)."""
    return {s: signal.signal(s, handler) for s in STOP_SIGNALS}


def restore(old: dict[int, Any]) -> None:
    for s, h in old.items():
        signal.signal(s, h if h is not None else signal.SIG_DFL)


def ignore_in_child() -> None:
    """In a child process of the run: the whole process group gets the terminal's signals; the daemon decides."""
    install(signal.SIG_IGN)


class RunGuard:
    """The daemon's handler for the whole run. During start-up the first stop signal raises ``Interrupted``
    (so the start-up's cleanup runs); from ``forward_to(stop)`` on, a signal asks the loop to stop (the loop
    installs its own handler while it runs; this one covers the instants before and after); after
    ``shutting_down()`` signals are only counted, so the log's footer and the summary get written."""

    def __init__(self) -> None:
        self.raise_on_signal = True
        self.forward: Callable[[str], None] | None = None
        self.received: list[int] = []

    def __call__(self, signum: int, _frame: Any) -> None:
        self.received.append(signum)
        if self.forward is not None:
            self.forward(signal.Signals(signum).name)
        elif self.raise_on_signal:
            self.raise_on_signal = False
            raise Interrupted(signum)

    def forward_to(self, stop: Callable[[str], None]) -> None:
        self.forward = stop
        self.raise_on_signal = False

    def shutting_down(self) -> None:
        self.forward = None
        self.raise_on_signal = False
