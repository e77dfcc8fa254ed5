"""The controller's design made in a short-lived helper process, so the real-time control process never
imports what it takes: the gains (eq. 7, or LQR and pole placement through python-control) and the arm
observer's matrices (scipy's expm and discrete Riccati solver) are plain arrays once made. Imported into the
control process, scipy would stay there for the whole run, its shared libraries and OpenBLAS buffers locked
in memory by mlockall, for arithmetic done once before the first tick.

Started first in the run's start-up ('spawn', like the logger), in parallel with the logger and the mock;
the arrays come back over a pipe (no named semaphores, as furuta_rt.runtime.channel explains).

The design is a pure function of the rig, the given gains and the code that computes it, so the arrays are kept
(an .npz of plain arrays, no pickle) in the build folder (``firmware_protocol.hostbuild.build_dir``: the clone's
``build/``) under a key hashing exactly those: the effective rig's every value, the gains, the bytes of every
furuta_rt source file and where (and when) numpy, scipy and python-control were installed. The next run of the
same rig and code starts no helper: the helper's interpreter and its scipy import were most of a run's start-up.
``FURUTA_RT_DESIGN_CACHE=0`` turns the cache off.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import importlib.util
import multiprocessing
import os
import tempfile
import time
import zipfile
from multiprocessing.connection import Connection, Pipe
from pathlib import Path
from typing import Any

from furuta_rt.config import RigConfig
from furuta_rt.errors import UserError

DESIGN_TIMEOUT_S = 60.0  # a helper that has not answered by then has failed (its imports take seconds under load)
PACKAGE_DIR = Path(__file__).resolve().parent.parent
DESIGN_LIBRARIES = ("numpy", "scipy", "control")  # what controller_design computes with


def design_key(rig: RigConfig, gains: list[float] | None) -> str:
    """What the design depends on, hashed: the rig's every value, the gains, furuta_rt's source and the
    libraries' installations (the location, size and time of each one's ``__init__.py``)."""
    h = hashlib.sha256()
    h.update(rig.model_dump_json().encode())
    h.update(repr(None if gains is None else [float(g) for g in gains]).encode())
    for path in sorted(PACKAGE_DIR.rglob("*.py")):
        h.update(str(path.relative_to(PACKAGE_DIR)).encode())
        h.update(path.read_bytes())
    for name in DESIGN_LIBRARIES:
        spec = importlib.util.find_spec(name)
        origin = spec.origin if spec is not None else None
        st = os.stat(origin) if origin else None
        h.update(f"{name} {origin} {st and st.st_size} {st and st.st_mtime_ns}".encode())
    return h.hexdigest()[:24]


def _cache_path(key: str) -> Path | None:
    """The design's file in the build folder (None: the cache is off)."""
    if os.environ.get("FURUTA_RT_DESIGN_CACHE", "1") == "0":
        return None
    from firmware_protocol.hostbuild import build_dir

    return build_dir() / "designs" / f"design-{key}.npz"


def _load(path: Path) -> Any:
    """The ControllerDesign kept in ``path``; None if there is none or it cannot be read as one."""
    from furuta_rt.controller.controller import ControllerDesign
    from furuta_rt.controller.observer import ArmObserverDesign

    try:
        import numpy as np

        with np.load(path, allow_pickle=False) as data:
            observer = {f.name: data[f"observer.{f.name}"] for f in dataclasses.fields(ArmObserverDesign)}
            gains = data["gains"]
        observer = {k: float(v) if v.ndim == 0 else v for k, v in observer.items()}
        return ControllerDesign(gains=gains, observer=ArmObserverDesign(**observer))
    except (OSError, KeyError, ValueError, TypeError, EOFError, zipfile.BadZipFile):  # absent or torn: made again
        return None


def _store(path: Path, design: Any) -> None:
    """Keep ``design`` in ``path`` (written aside and renamed: a reader never sees half a file); a build
    folder that cannot be written keeps nothing."""
    import numpy as np

    arrays = {f"observer.{f.name}": np.asarray(getattr(design.observer, f.name))
              for f in dataclasses.fields(design.observer)}
    with contextlib.suppress(OSError):
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=".design-", suffix=".npz", dir=path.parent)
        try:
            with os.fdopen(fd, "wb") as f:
                np.savez(f, gains=np.asarray(design.gains, dtype=float), **arrays)
            os.replace(tmp, path)
        finally:
            with contextlib.suppress(OSError):
                os.unlink(tmp)


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
    """The helper, running; ``result()`` waits for its ControllerDesign (or the kept one: no helper)."""

    def __init__(self, rig: RigConfig, gains: list[float] | None) -> None:
        try:
            self._path = _cache_path(design_key(rig, gains))
        except OSError:  # a source file or folder this process may not read: no key, the helper makes it
            self._path = None
        self._kept = None if self._path is None else _load(self._path)
        self._proc: Any = None
        if self.kept:
            return
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

    @property
    def kept(self) -> bool:
        """The design was kept from an earlier run: no helper started."""
        return self._kept is not None

    def result(self, timeout: float = DESIGN_TIMEOUT_S) -> Any:
        """The ControllerDesign; UserError (one line) if the design failed or the helper died or hung."""
        if self._kept is not None:
            return self._kept
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
        if self._path is not None:
            _store(self._path, reply[1])
        return reply[1]

    def close(self) -> None:
        """End the helper if it still runs (start-up interrupted); idempotent."""
        if self._proc is None:
            return
        if self._proc.is_alive():
            self._proc.join(0.5)
        if self._proc.is_alive():
            self._proc.terminate()
            self._proc.join(5.0)
        self._conn.close()
