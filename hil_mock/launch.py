"""Run ``hil-mock`` as a subprocess (tests, ``furuta-rt run --mock``) and wait for its port."""

from __future__ import annotations

import select
import signal
import subprocess
import sys
import time
from collections.abc import Sequence

from hil_mock.cli import SERVING_PREFIX


class MockStartError(RuntimeError):
    """hil-mock exited or stayed silent instead of printing its port."""


def start_mock_subprocess(args: Sequence[str] = (), timeout: float = 30.0) -> tuple[subprocess.Popen[str], str]:
    """Start ``python -m hil_mock --pty *args``; return (process, pty path) once it serves.

    stdout and stderr are pipes (text). Stop it with :func:`stop_mock_subprocess`, which returns its
    statistics. Raises MockStartError with hil-mock's own error line if it fails to start.
    """
    proc = subprocess.Popen(
        [sys.executable, "-m", "hil_mock", "--pty", *args],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    assert proc.stdout is not None and proc.stderr is not None
    deadline = time.monotonic() + timeout
    while True:
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            proc.kill()
            _, err = proc.communicate()
            raise MockStartError(f"hil-mock printed no port within {timeout:g} s: {err.strip()}")
        ready, _, _ = select.select([proc.stdout], [], [], min(remaining, 0.5))
        if ready:
            line = proc.stdout.readline()
            if line.startswith(SERVING_PREFIX):
                return proc, line[len(SERVING_PREFIX):].strip()
            if not line:  # EOF: it exited
                _, err = proc.communicate()
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
    return err
