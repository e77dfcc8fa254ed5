"""Run ``hil-mock`` as a subprocess (tests, ``furuta-rt run --mock``) and wait for its port.

The child ends with its parent: it gets the read end of a pipe (``--exit-with-fd``) whose only write end
stays in this process, so when this process dies, however (SIGKILL included), the child reads end of file,
zeroes its actuator, closes its pty and exits.

The child runs in a session of its own: a terminal's signals (Ctrl-C, Ctrl-\\, a closed terminal's SIGHUP) go
to the parent's process group and not to it, so a run stopped that way still reaches the device with its
u = 0 and STOP (the device dying first would hang up under the host instead). It stops when the parent says
(``stop_mock_subprocess``) or dies.
"""

from __future__ import annotations

import contextlib
import os
import select
import signal
import subprocess
import sys
import time
from collections.abc import Sequence

SERVING_PREFIX = "hil-mock: serving on "
"""The line ``hil-mock`` prints once it serves, followed by its pty path (read here, printed by the CLI)."""

_LIFELINES: dict[int, int] = {}
"""pid of each mock started here → the write end of its lifeline pipe."""


class MockStartError(RuntimeError):
    """hil-mock exited or stayed silent instead of printing its port."""


def start_mock_subprocess(args: Sequence[str] = (), timeout: float = 30.0) -> tuple[subprocess.Popen[str], str]:
    """Start ``python -m hil_mock --pty *args``; return (process, pty path) once it serves.

    stdout and stderr are pipes (text). Stop it with :func:`stop_mock_subprocess`, which returns its
    statistics. Raises MockStartError with hil-mock's own error line if it fails to start.
    """
    watch_r, watch_w = os.pipe()  # both close-on-exec: only the child's copy of watch_r crosses exec
    try:
        proc = subprocess.Popen(
            [sys.executable, "-m", "hil_mock", "--pty", "--exit-with-fd", str(watch_r), *args],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, pass_fds=(watch_r,), start_new_session=True,
        )
    except BaseException:
        os.close(watch_w)
        raise
    finally:
        os.close(watch_r)
    _LIFELINES[proc.pid] = watch_w
    assert proc.stdout is not None and proc.stderr is not None
    deadline = time.monotonic() + timeout
    while True:
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            proc.kill()
            _, err = proc.communicate()
            _cut_lifeline(proc)
            raise MockStartError(f"hil-mock printed no port within {timeout:g} s: {err.strip()}")
        ready, _, _ = select.select([proc.stdout], [], [], min(remaining, 0.5))
        if ready:
            line = proc.stdout.readline()
            if line.startswith(SERVING_PREFIX):
                return proc, line[len(SERVING_PREFIX):].strip()
            if not line:  # EOF: it exited
                _, err = proc.communicate()
                _cut_lifeline(proc)
                raise MockStartError(f"hil-mock exited with code {proc.returncode}: {err.strip()}")


def stop_mock_subprocess(proc: subprocess.Popen[str], timeout: float = 10.0) -> str:
    """SIGINT, wait, return what it printed on stderr (its statistics). Kills it if it hangs."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
    try:
        _, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        _, err = proc.communicate()
    finally:
        _cut_lifeline(proc)
    return err



def _cut_lifeline(proc: subprocess.Popen[str]) -> None:
    fd = _LIFELINES.pop(proc.pid, None)
    if fd is not None:
        with contextlib.suppress(OSError):
            os.close(fd)
