"""The MCAP logger process, fed tick batches through a bounded queue by the control loop; with
``--foxglove`` it also serves the same messages live (furuta_rt.runtime.live), so nothing of the live
view runs in the control process (with ``--foxglove`` and no ``--log`` it only serves).

The file is written by furuta_rt.io.mcap_log.LogWriter (exactly the layout of furuta_rt.io.log_schema:
/furuta/tick, /furuta/timing, /furuta/joint_states, /furuta/events, /furuta/tick_batch; metadata "rig", "run", "device";
the attachment "rig.toml"). This process turns the loop's tuples into those messages and flushes the
chunk in progress about every second, so a killed run leaves a file readable up to its last second.
JSON encoding and zstd compression happen here, never in the control process (their GIL time would
make ticks late).

Queue items, in order:
    ("event", (wall_ns, level, message))        may come before "open" (kept until then)
    ("open", {device metadata}[, {run metadata}])  after the handshake: the file is written from here on
    ("ticks", [tuple in records.TICK_RECORD order, ...])
    ("metadata", name, {key: value})            a metadata record taken during the run (the swing-up's calibration)
    ("close", summary_text)
"""

from __future__ import annotations

import contextlib
import multiprocessing
import queue
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from furuta_rt.config import RigConfig
from furuta_rt.errors import UserError
from furuta_rt.io.mcap_log import LogNotInPlace, LogWriter
from furuta_rt.runtime.live import LiveView, start_live_view
from furuta_rt.runtime.records import TICK_RECORD, TimeBase, tick_fields, timing_fields
from furuta_rt.runtime.signals import ignore_in_child as ignore_stop_signals

_DEV, _SEQ, _FC = (TICK_RECORD.index(name) for name in ("dev_ns", "seq", "fc_hat"))


@dataclass
class LogSetup:
    """What the writer needs before the handshake (the device, and the run's port, come with "open");
    ``path`` None: no file (a live view only)."""

    path: str | None
    rig: RigConfig
    run: dict[str, str] = field(default_factory=dict)
    # End a chunk every 0.5 s: with the loop's 0.1 s batches and the writer's 0.2 s queue poll, a run
    # killed at any moment loses under 1 s of log (the reliability issue's bound), by construction.
    flush_s: float = 0.5
    foxglove_port: int | None = None  # serve the live view on this port (furuta_rt.runtime.live)
    foxglove_host: str = "127.0.0.1"  # ... on this address
    replace: bool = False  # an existing file at ``path`` may be replaced (run --force); else creating it fails


class TickLog:
    """Queue items → LogWriter. Used by the logger process (and directly by tests)."""

    def __init__(self, setup: LogSetup) -> None:
        self.setup = setup
        self.mode = setup.run.get("mode", "none")
        self.writer: LogWriter | None = None
        self._early: list[tuple[int, str, str]] = []
        self.ticks = 0
        self._base = TimeBase()  # the device clock → wall clock map, fixed over the first ticks

    def open(self, device: dict[str, str], run: dict[str, str] | None = None) -> None:
        """Create the file with its metadata (``run`` replaces the setup's, when given)."""
        if run is not None:
            self.setup.run = run
            self.mode = run.get("mode", "none")
        self.writer = LogWriter(self.setup.path, self.setup.rig, self.setup.run, device, exclusive=not self.setup.replace)
        for ev in self._early:
            self.writer.event(*ev)
        self._early.clear()
        self.writer.flush()

    def write_ticks(self, batch: list[tuple], last: bool = False) -> None:
        """Write ``batch`` once the time base is fixed (held until then); ``last``: the run ends, and the ticks still
        held are written on the map of those there are."""
        w = self.writer
        assert w is not None
        mapped = self._base.offset_ns is not None
        batch = self._base.add(batch)
        if last:
            batch = batch + self._base.release()
        if not batch:
            return
        mode = self.mode
        if not mapped:  # the window just closed: its map goes into the log once
            w.time_base(self._base.metadata)
        offset = self._base.offset_ns
        for rec in batch:
            ns = rec[_DEV] + offset
            w.tick(ns, tick_fields(rec, mode), timing_fields(rec))
            if mode == "adaptive":
                w.compensation(ns, rec[_SEQ], rec[_FC])
        self.ticks += len(batch)

    def event(self, wall_ns: int, level: str, message: str) -> None:
        if self.writer is None:
            self._early.append((wall_ns, level, message))
        else:
            self.writer.event(wall_ns, level, message)

    def handle(self, item: tuple) -> bool:
        """Apply one queue item; False on "close"."""
        kind = item[0]
        if kind == "ticks":
            self.write_ticks(item[1])
        elif kind == "event":
            self.event(*item[1])
        elif kind == "open":
            self.open(*item[1:])
        elif kind == "metadata" and self.writer is not None:
            self.writer.metadata(item[1], item[2])
        elif kind == "close":
            if item[1]:
                self.event(time.time_ns(), "INFO", item[1])
            return False
        return True

    def flush(self) -> None:
        if self.writer is not None:
            self.writer.flush()

    def close(self) -> None:
        """Finish the file (a run that never reached the handshake still gets its events, unless that
        would replace an existing file: only a run with data replaces one)."""
        if self.writer is None:
            if Path(self.setup.path).exists():
                return
            self.open({})
        self.write_ticks([], last=True)  # a run shorter than the time base's window
        self.writer.close()  # type: ignore[union-attr]


def _failure(path: str, err: Exception) -> str:
    cause = err.strerror if isinstance(err, OSError) and err.strerror else str(err)
    return f"cannot write the log {path}: {cause}; the loop goes on, the log ends here"


def logger_process(setup: LogSetup, q: Any, ready: Any, failed: Any = None, opened: Any = None,
                   live_failed: Any = None) -> None:
    """Entry point of the logger process (spawned). Ends on "close" or when the parent dies.

    A write error (disk full, file too large, ...) is said in one line on stderr and flagged in
    ``failed`` (an Event the daemon checks); the process then keeps draining the queue without writing,
    so the control process is never blocked by it.
    """
    ignore_stop_signals()  # Ctrl-C or a closed terminal reaches the whole group: the daemon decides
    log: TickLog | None = TickLog(setup) if setup.path else None
    live: LiveView | None = (start_live_view(setup.foxglove_port, setup.foxglove_host, live_failed)
                             if setup.foxglove_port else None)
    ready.set()
    parent = multiprocessing.parent_process()
    last_flush = time.monotonic()

    def fail(err: Exception) -> None:
        nonlocal log
        said = str(err) if isinstance(err, LogNotInPlace) else _failure(str(setup.path), err)
        print(f"furuta-rt: error: {said}", file=sys.stderr, flush=True)
        if failed is not None:
            failed.set()
        if log is not None and log.writer is not None:
            with contextlib.suppress(Exception):  # whatever still fits; the file is readable up to its last chunk
                log.writer.close()
        log = None

    while True:
        gone = False
        try:
            item = q.get(timeout=0.2)
        except queue.Empty:
            item = None
        except (EOFError, OSError):  # the writer's end closed: the control process is gone
            item, gone = None, True
        if live is not None and item is not None:
            live = live.handle(item)
        if item is not None and item[0] == "close" and log is None:
            break
        try:
            if log is not None and item is not None and not log.handle(item):
                break
            if opened is not None and item is not None and item[0] == "open" and log is not None:
                opened.set()  # the file is ours (created or replaced by this run): its ticks are this run's
            now = time.monotonic()
            if log is not None and now - last_flush >= setup.flush_s:
                log.flush()
                last_flush = now
                gone = log.writer.not_in_place() if log.writer is not None else None
                if gone:  # said at once, and the run ends with exit 3 (its log is not where it says)
                    raise LogNotInPlace(gone)
        except (OSError, UserError) as err:
            fail(err)
        if gone or (item is None and parent is not None and not parent.is_alive()):
            if log is not None:
                with contextlib.suppress(OSError, UserError):
                    log.event(time.time_ns(), "ERROR", "the control process ended without closing the log")
            break
    if live is not None:
        live.close()
    if log is not None:
        try:
            log.close()
        except (OSError, UserError) as err:
            fail(err)
