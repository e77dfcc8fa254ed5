"""Which 1 kHz misses were the machine's: a kernel trace of the loop's CPU laid over the run's own ticks.

With `run --cpu N` everything a SAMPLE → COMMAND round trip waits for runs on CPU N: the loop, hil-mock's device
thread and the kernel's tty work. While it runs, an ftrace instance of its own records that CPU's scheduling events
(sched_switch, sched_waking) on CLOCK_MONOTONIC, streamed to a file. A woken task on a CPU that is otherwise idle or
busy with our few-µs ticks runs within microseconds; when the CPU records no event at all for longer than
``SILENCE_S`` while a task it woke is waiting to run, the CPU was not running — on a virtual machine, the hypervisor
had descheduled it. The same holds at each of the device's deadlines: its timer fires there (the CPU records the
wake-up), so a CPU that records nothing from just before a deadline to ``SILENCE_S`` after it was not running either.
Each miss of the run (its log's COMMAND_LATE ticks, and the periods hil-mock skipped) is a window of device time,
mapped onto the same clock by hil-mock's ``clock_origin_s``; a miss whose window holds either kind of silence is the
machine's, the others are left to the stack.
"""

from __future__ import annotations

import contextlib
import os
import re
import select
import threading
from pathlib import Path
from typing import Any

import numpy as np

TRACEFS = Path("/sys/kernel/tracing")
INSTANCE = "furuta-bench"
SILENCE_S = 300e-6
"""A CPU that records nothing for this long while a task it woke waits has not been running: our ticks' pieces (the
device's tick, the kworker's flush, the host's update) each take tens of µs, and a woken task runs at once."""
_LINE = re.compile(r"\[(\d+)\]\s+\S+\s+(\d+\.\d+): (sched_switch|sched_waking): (.*)$")


class CpuTrace:
    """Record one CPU's scheduling events to ``path`` while the context is open; ``ok`` says whether it could
    (root and tracefs needed; nothing is traced otherwise)."""

    def __init__(self, cpu: int, path: Path) -> None:
        self.cpu, self.path = cpu, path
        self.ok = False
        self.why = ""
        self._dir = TRACEFS / "instances" / INSTANCE
        self._reader: threading.Thread | None = None
        self._done = threading.Event()

    def _write(self, name: str, value: str) -> None:
        (self._dir / name).write_text(value)

    def __enter__(self) -> CpuTrace:
        try:
            with contextlib.suppress(FileNotFoundError):  # left by a bench that was killed
                self._dir.rmdir()
            self._dir.mkdir()
            self._write("tracing_on", "0")
            self._write("trace_clock", "mono")
            self._write("buffer_size_kb", "8192")
            self._write("tracing_cpumask", format(1 << self.cpu, "x"))
            for event in ("sched/sched_switch", "sched/sched_waking"):
                self._write(f"events/{event}/enable", "1")
            self._write("tracing_on", "1")
        except OSError as err:
            self.why = f"no kernel trace ({err.strerror or err}: needs root and tracefs)"
            self._remove()
            return self
        self.ok = True
        self._reader = threading.Thread(target=self._stream, name="bench trace", daemon=True)
        self._reader.start()
        return self

    def _stream(self) -> None:
        others = os.sched_getaffinity(0) - {self.cpu}
        if others:  # the reader's wake-ups must not compete with the traced CPU's work
            os.sched_setaffinity(0, others)
        fd = os.open(self._dir / "trace_pipe", os.O_RDONLY | os.O_NONBLOCK)  # a blocking read never returns once
        # tracing stops, and holds the instance busy
        poller = select.poll()
        poller.register(fd, select.POLLIN)
        try:
            with open(self.path, "wb") as out:
                while True:
                    poller.poll(100)
                    try:
                        chunk = os.read(fd, 1 << 16)
                    except BlockingIOError:
                        if self._done.is_set():
                            return
                        continue
                    except OSError:
                        return
                    if not chunk and self._done.is_set():
                        return
                    out.write(chunk)
        finally:
            os.close(fd)

    def __exit__(self, *exc: object) -> None:
        if not self.ok:
            return
        with contextlib.suppress(OSError):
            self._write("tracing_on", "0")
        self._done.set()  # the reader drains what is buffered, then closes the pipe
        if self._reader is not None:
            self._reader.join(30.0)
        self._remove()

    def _remove(self) -> None:
        with contextlib.suppress(OSError):
            for event in ("sched/sched_switch", "sched/sched_waking"):
                self._write(f"events/{event}/enable", "0")
        for _ in range(50):  # busy while the reader still holds trace_pipe open
            try:
                self._dir.rmdir()
                return
            except FileNotFoundError:
                return
            except OSError:
                threading.Event().wait(0.1)


def read_events(path: Path, cpu: int) -> tuple[np.ndarray, np.ndarray]:
    """The times (monotonic s) of ``cpu``'s events, and for each whether a task it had woken was waiting to run just
    after it (set by a sched_waking aimed at ``cpu``, cleared by the next sched_switch)."""
    times: list[float] = []
    waiting_after: list[bool] = []
    waiting = False
    with open(path, "rb") as f:
        for raw in f:
            m = _LINE.search(raw.decode(errors="replace"))
            if m is None or int(m.group(1)) != cpu:
                continue
            if m.group(3) == "sched_waking":
                waiting = waiting or f"target_cpu={cpu:03d}" in m.group(4)
            else:
                waiting = False
            times.append(float(m.group(2)))
            waiting_after.append(waiting)
    return np.array(times), np.array(waiting_after, dtype=bool)


def waiting_silences(events: np.ndarray, waiting: np.ndarray, min_s: float = SILENCE_S) -> tuple[np.ndarray, np.ndarray]:
    """(starts, ends), monotonic seconds, of the stretches ≥ ``min_s`` in which the CPU recorded no event while a task
    it had woken waited to run (``read_events``)."""
    gap = np.flatnonzero(waiting[:-1] & (np.diff(events) >= min_s))
    return events[gap], events[gap + 1]


def deadline_silences(events: np.ndarray, deadlines: np.ndarray, min_s: float = SILENCE_S,
                      early_s: float = 150e-6) -> np.ndarray:
    """Whether the CPU recorded nothing from ``early_s`` before each deadline to ``min_s`` after it (the device's
    timer, set to wake it shortly before the deadline, could not fire: the CPU was not running)."""
    i = np.searchsorted(events, deadlines - early_s)
    nxt = np.where(i < len(events), events[np.minimum(i, len(events) - 1)], np.inf)
    return nxt - deadlines >= min_s


def attribute(log_path: Path, trace_path: Path, cpu: int, clock_origin_s: float, rate: float) -> dict[str, Any]:
    """The run's misses, each the window of device time from the SAMPLE it concerns to the next tick (a COMMAND_LATE
    on tick k+1 is about SAMPLE k; a jump of the device's clock is hil-mock's skipped periods), mapped onto the
    monotonic clock; how many of them hold a silence of the loop's CPU (``waiting_silences``,
    ``deadline_silences``)."""
    from firmware_protocol import StatusFlags
    from furuta_rt.io.mcap_read import read_log

    ticks = read_log(log_path, timing=False, events=False).ticks
    t = clock_origin_s + np.asarray(ticks["t"], dtype=float)
    period = 1.0 / rate
    late = np.flatnonzero((np.asarray(ticks["status"]) & int(StatusFlags.COMMAND_LATE))[1:] != 0)
    skipped = np.flatnonzero(np.diff(t) > 1.5 * period)
    windows = [(t[k], t[k + 1]) for k in (*late, *skipped)]
    events, waiting = read_events(trace_path, cpu)
    starts, ends = waiting_silences(events, waiting)
    explained = at_deadline = 0
    for a, b in windows:
        if np.any((starts < b) & (ends > a - 0.2 * period)):  # a silence overlapping the window (or just before it)
            explained += 1
            continue
        deadlines = a + period * np.arange(0, round((b - a) / period) + 1)
        if np.any(deadline_silences(events, deadlines)):
            explained += 1
            at_deadline += 1
    span = (t[0], t[-1]) if len(t) else (0.0, 0.0)
    inside = (starts >= span[0]) & (ends <= span[1])
    return {"miss_windows": len(windows), "with_cpu_silence": explained, "of_them_at_a_deadline": at_deadline,
            "without": len(windows) - explained,
            "silences_in_run": int(np.sum(inside)),
            "silence_total_ms": float(np.sum(ends[inside] - starts[inside]) * 1e3),
            "silence_longest_ms": float(np.max(ends[inside] - starts[inside]) * 1e3) if np.any(inside) else 0.0,
            "silence_threshold_us": SILENCE_S * 1e6}
