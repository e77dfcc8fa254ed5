"""The controller's design made in a short-lived helper process, so the real-time control process never
imports what it takes: the gains (eq. 7, or LQR and pole placement through python-control) and the arm
observer's matrices (scipy's expm and discrete Riccati solver) are plain arrays once made. Imported into the
control process, scipy would stay there for the whole run, its shared libraries and OpenBLAS buffers locked
in memory by mlockall, for arithmetic done once before the first tick.

Started first in the run's start-up ('spawn', like the logger), in parallel with the logger and the mock;
the arrays come back over a pipe (no named semaphores, as furuta_rt.runtime.channel explains).
"""

from __future__ import annotations

import multiprocessing
import time
from multiprocessing.connection import Connection, Pipe
from typing import Any

from furuta_rt.config import RigConfig
from furuta_rt.errors import UserError

DESIGN_TIMEOUT_S = 60.0  # a helper that has not answered by then has failed (its imports take seconds under load)


def _make(conn: Connection, rig: RigConfig, gains: list[float] | None) -> None:
    """The helper's entry point: send ("ok", ControllerDesign) or ("error", is a UserError, message)."""
    from furuta_rt.runtime.signals import ignore_in_child

    ignore_in_child()  # the terminal's signals reach the whole group: the daemon decides
    try:
        from furuta_rt.controller.controller import controller_design

        conn.send(("ok", controller_design(rig, gains)))
    except Exception as err:  # said by the daemon in one line
        user = isinstance(err, UserError)
        conn.send(("error", user, str(err) if user else f"{type(err).__name__}: {err}"))
    finally:
        conn.close()


class DesignProcess:
    """The helper, running; ``result()`` waits for its ControllerDesign."""

    def __init__(self, rig: RigConfig, gains: list[float] | None) -> None:
        ctx = multiprocessing.get_context("spawn")
        self._conn, child_end = Pipe(duplex=False)
        self._proc = ctx.Process(target=_make, args=(child_end, rig, gains), name="furuta-rt-design")
        try:
            self._proc.start()
        except (OSError, ImportError) as err:  # no interpreter to start (unreadable, gone): one line, nothing started
            self._conn.close()
            raise UserError(f"cannot start the controller design process ({type(err).__name__}: {err}); "
                            "nothing was started") from None
        finally:
            child_end.close()

    def result(self, timeout: float = DESIGN_TIMEOUT_S) -> Any:
        """The ControllerDesign; UserError (one line) if the design failed or the helper died or hung."""
        end = time.monotonic() + timeout
        try:
            while not self._conn.poll(0.05):
                if not self._proc.is_alive() and not self._conn.poll(0):
                    raise UserError(f"the controller design process died (exit code {self._proc.exitcode}); "
                                    "nothing was started")
                if time.monotonic() > end:
                    raise UserError(f"the controller design process did not answer within {timeout:g} s")
            reply = self._conn.recv()
        except EOFError:
            self._proc.join(1.0)
            raise UserError(f"the controller design process died (exit code {self._proc.exitcode})") from None
        finally:
            self.close()
        if reply[0] == "error":
            _, is_user_error, message = reply
            raise UserError(message if is_user_error else f"the controller design failed: {message}")
        return reply[1]

    def close(self) -> None:
        """End the helper if it still runs (start-up interrupted); idempotent."""
        if self._proc.is_alive():
            self._proc.join(0.5)
        if self._proc.is_alive():
            self._proc.terminate()
            self._proc.join(5.0)
        self._conn.close()
