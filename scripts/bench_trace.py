"""Which 1 kHz misses were the machine's: a kernel trace of the loop's CPU laid over the run's own ticks.

With `run --cpu N` everything a SAMPLE → COMMAND round trip waits for runs on CPU N: the loop, hil-mock's device
thread and the kernel's tty work. While it runs, an ftrace instance of its own records that CPU's scheduling events
(sched_switch, sched_waking, and sched_stat_runtime: the run time the kernel charges a task, which leaves out time
the hypervisor stole) on CLOCK_MONOTONIC, streamed to a file. A task woken onto a CPU that is idle or busy with our
few-µs ticks runs within microseconds, and a running task is charged the time it holds the CPU. So when a task was
ready on the CPU and, for ``SILENCE_S`` or longer, nothing ran it — nothing recorded while it waited on an idle CPU,
or it was charged that much less than the time since it was woken or last charged — the CPU was not running: on a
virtual machine, the hypervisor had it. The same holds at each of the device's deadlines: its timer fires there (the
CPU records the wake-up), so a CPU that records nothing from just before a deadline to ``SILENCE_S`` after it was not
running either. A woken task that waited that long while another task ran, and was charged, is load, not the
machine; the trace names the holder.
Each miss of a run (its log's COMMAND_LATE ticks, and the periods hil-mock skipped; or a bare pair's missed periods)
is a window of monotonic time (hil-mock's ``clock_origin_s`` maps device time onto it); a miss whose window meets
time the CPU lost is the machine's, the others are left unexplained.
"""

from __future__ import annotations

import contextlib
import os
import re
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

TRACEFS = Path("/sys/kernel/tracing")
INSTANCE = "furuta-bench"
SILENCE_S = 300e-6
"""A CPU that records nothing for this long while a task it woke waits has not been running: our ticks' pieces (the
device's tick, the kworker's flush, the host's update) each take tens of µs, and a woken task runs at once."""
READ_EVERY_S = 0.05
"""How often the reader drains the trace (the buffer holds seconds of events)."""
EVENTS = ("sched/sched_switch", "sched/sched_waking", "sched/sched_stat_runtime")
_LINE = re.compile(r"^\s*(.*)-(\d+)\s+\[(\d+)\]\s+\S+\s+(\d+\.\d+): (sched_switch|sched_waking|sched_stat_runtime): (.*)$")
_SWITCH = re.compile(r"prev_pid=(\d+) prev_prio=\d+ prev_state=(\S+) ==> next_comm=(.*) next_pid=(\d+) next_prio=(\d+)")
_WOKEN = re.compile(r"pid=(\d+) prio=(\d+) target_cpu=(\d+)")
_CHARGED = re.compile(r"pid=(\d+) runtime=(\d+)")


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
            for event in EVENTS:
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
        """Copy trace_pipe to the file every ``READ_EVERY_S``. The pipe is never waited on (no poll, no blocking
        read): a waiting reader makes the ring buffer wake it, by an interrupt on the traced CPU, for every event
        recorded there — and that wake-up is itself an event, so the reader's wake-ups would fill the trace and
        load the very CPU it measures."""
        others = set(range(os.cpu_count() or 1)) - {self.cpu}  # this process may be pinned to the traced CPU
        with contextlib.suppress(OSError):  # the reader's work must not compete with the traced CPU's
            os.sched_setaffinity(0, others)
        fd = os.open(self._dir / "trace_pipe", os.O_RDONLY | os.O_NONBLOCK)
        try:
            with open(self.path, "wb") as out:
                while True:
                    done = self._done.wait(READ_EVERY_S)  # set once tracing is off: one last drain, then stop
                    while True:
                        try:
                            chunk = os.read(fd, 1 << 16)
                        except BlockingIOError:
                            break
                        except OSError:
                            return
                        if not chunk:
                            break
                        out.write(chunk)
                    if done:
                        return
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
            for event in EVENTS:
                self._write(f"events/{event}/enable", "0")
        for _ in range(50):  # busy while the reader still holds trace_pipe open
            try:
                self._dir.rmdir()
                return
            except FileNotFoundError:
                return
            except OSError:
                threading.Event().wait(0.1)


@dataclass
class CpuTimeline:
    """One CPU's trace reduced to the stretches in which it lost time (monotonic seconds).

    - ``lost``: ≥ ``SILENCE_S`` in which a task was ready on the CPU and nothing ran it — the CPU was idle with a
      task it had woken waiting and recorded nothing, or a task was charged that much less than the time since it
      was woken or last charged (the kernel's run time leaves out time the hypervisor stole). Either way the CPU
      was not running: on a virtual machine, the hypervisor had it.
    - ``held``: a task it had woken waited ≥ ``SILENCE_S`` while another task ran, and was charged for it — load,
      not the machine: the holder's name is kept.
    ``events`` are the times of all its events, ``by_idle`` whether the idle task was running when each was
    recorded (``deadline_silences``)."""

    events: np.ndarray
    lost: np.ndarray  # (n, 2) starts, ends
    held: list[tuple[float, float, str]] = field(default_factory=list)
    by_idle: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))


def read_timeline(path: Path, cpu: int, min_s: float = SILENCE_S) -> CpuTimeline:
    """``cpu``'s events in a trace of sched_switch, sched_waking and sched_stat_runtime lines (trace_pipe's text).

    Each line names the task that was running when it was recorded; a task that appears without a sched_switch to
    it came off the idle task (this kernel records no switch out of idle). Its charged time then runs from its
    wake-up: on a CPU that was running, a task woken onto it idle starts within microseconds."""
    times: list[float] = []
    by_idle: list[bool] = []
    lost: list[tuple[float, float]] = []
    runs: list[tuple[float, float, str]] = []  # who held the CPU: (from, to, "comm (prio)")
    waits: list[tuple[float, float]] = []  # a woken or preempted task waiting ≥ min_s behind another
    prio: dict[int, str] = {}
    current: int | None = None  # the running task's pid (0: idle); unknown until the first event
    holder, run_start = "", 0.0
    charged_since = 0.0  # when the running task's charged time was last brought up to date
    waiting: dict[int, float] = {}  # pid → since when it has been waiting to run on this CPU
    last: float | None = None
    with open(path, "rb") as f:
        for raw in f:
            m = _LINE.search(raw.decode(errors="replace"))
            if m is None or int(m.group(3)) != cpu:
                continue
            t, kind, rest = float(m.group(4)), m.group(5), m.group(6)
            running = int(m.group(2))
            if running != current:  # switched to without a recorded switch: off the idle task
                if current not in (None, 0):
                    runs.append((run_start, t, holder))
                woken = waiting.pop(running, None)
                charged_since = run_start = woken if woken is not None and current == 0 else (last or t)
                current, holder = running, f"{m.group(1).strip()} (prio {prio.get(running, '?')})"
            elif last is not None and waiting and current == 0 and t - last >= min_s:
                lost.append((last, t))  # idle, with a task waiting to run, and nothing recorded
            if kind == "sched_waking":
                w = _WOKEN.search(rest)
                if w is not None:
                    prio[int(w.group(1))] = w.group(2)
                    if int(w.group(3)) == cpu:
                        waiting.setdefault(int(w.group(1)), t)
            elif kind == "sched_stat_runtime":
                c = _CHARGED.search(rest)
                if c is not None and int(c.group(1)) == current:
                    if (t - charged_since) - int(c.group(2)) * 1e-9 >= min_s:
                        lost.append((charged_since, t))
                    charged_since = t
            elif (n := _SWITCH.search(rest)) is not None:
                if current not in (None, 0):
                    runs.append((run_start, t, holder))
                if n.group(2).startswith("R") and current != 0:  # preempted: still runnable, waiting again (the
                    # idle task always leaves in state R)
                    waiting.setdefault(int(n.group(1)), t)
                nxt = int(n.group(4))
                prio[nxt] = n.group(5)
                since = waiting.pop(nxt, None)
                if since is not None and t - since >= min_s:
                    waits.append((since, t))
                current, holder, run_start, charged_since = nxt, f"{n.group(3)} (prio {n.group(5)})", t, t
                if current == 0:  # the CPU goes idle only when nothing is left to run on it
                    waiting.clear()
            times.append(t)
            by_idle.append(running == 0)
            last = t
    starts, ends = np.array([r[0] for r in runs]), np.array([r[1] for r in runs])
    held = [(a, b, who) for a, b in waits if (who := _longest_holder(runs, starts, ends, a, b))]
    return CpuTimeline(np.array(times), np.array(lost).reshape(-1, 2), held, np.array(by_idle, dtype=bool))


def _longest_holder(runs: list[tuple[float, float, str]], starts: np.ndarray, ends: np.ndarray, a: float,
                    b: float) -> str:
    """The task that held the CPU longest between ``a`` and ``b`` ("" if only the idle task did); ``runs`` in time
    order, ``starts`` and ``ends`` their columns."""
    held: dict[str, float] = {}
    for i in range(int(np.searchsorted(ends, a, "right")), int(np.searchsorted(starts, b, "left"))):
        s, e, who = runs[i]
        held[who] = held.get(who, 0.0) + min(e, b) - max(s, a)
    return max(held, key=held.__getitem__) if held else ""


def deadline_silences(timeline: CpuTimeline, deadlines: np.ndarray, min_s: float = SILENCE_S,
                      early_s: float = 150e-6) -> np.ndarray:
    """Whether the CPU recorded nothing from ``early_s`` before each deadline to ``min_s`` after it, and was idle
    throughout (the next event is the idle task's: a task that ran in between would have recorded its switch out):
    the device's timer, set to wake it shortly before the deadline, could not fire — the CPU was not running. A task
    running across the deadline records nothing either; its charged time says whether the CPU ran it (``lost``)."""
    events = timeline.events
    i = np.searchsorted(events, deadlines - early_s)
    inside = i < len(events)
    nxt = np.where(inside, events[np.minimum(i, len(events) - 1)], np.inf)
    idle = np.where(inside, timeline.by_idle[np.minimum(i, len(events) - 1)], False)
    return (nxt - deadlines >= min_s) & idle


def _overlaps(spans: np.ndarray, a: float, b: float) -> bool:
    return bool(np.any((spans[:, 0] < b) & (spans[:, 1] > a))) if len(spans) else False


def attribute_windows(windows: list[tuple[float, float, int]], timeline: CpuTimeline, period: float) -> dict[str, Any]:
    """Each miss is a window of monotonic time, from the deadline of the round trip it concerns to the deadline it
    missed, and the periods it cost; it is the machine's when the window, or the fifth of a period before it,
    overlaps time the CPU lost, or the CPU recorded nothing across one of the window's deadlines
    (``deadline_silences``). The others stay unexplained; of those, the ones in which a woken task waited behind
    another say which task. Counts are periods."""
    counts = {"cpu_not_running": 0, "at_a_deadline": 0}
    holders: dict[str, int] = {}
    unexplained = 0
    held = np.array([(a, b) for a, b, _ in timeline.held]).reshape(-1, 2)
    for a, b, n in windows:
        lead = a - 0.2 * period
        if _overlaps(timeline.lost, lead, b):
            counts["cpu_not_running"] += n
        elif np.any(deadline_silences(timeline, a + period * np.arange(0, round((b - a) / period) + 1))):
            counts["at_a_deadline"] += n
        else:
            unexplained += n
            if len(held) and np.any(hit := (held[:, 0] < b) & (held[:, 1] > lead)):
                name = timeline.held[int(np.flatnonzero(hit)[0])][2]
                holders[name] = holders.get(name, 0) + n
    return {"misses": sum(counts.values()) + unexplained, "machine": sum(counts.values()), "machine_by_kind": counts,
            "unexplained": unexplained, "unexplained_behind_another_task": holders}


def timeline_figures(timeline: CpuTimeline, span: tuple[float, float]) -> dict[str, Any]:
    """How much time the CPU lost between ``span``'s ends."""
    lost = timeline.lost[(timeline.lost[:, 0] >= span[0]) & (timeline.lost[:, 1] <= span[1])]
    d = lost[:, 1] - lost[:, 0]
    return {"lost_stretches": len(d), "lost_total_ms": float(np.sum(d) * 1e3),
            "lost_longest_ms": float(np.max(d) * 1e3) if len(d) else 0.0, "threshold_us": SILENCE_S * 1e6}


def attribute(log_path: Path, trace_path: Path, cpu: int, clock_origin_s: float, rate: float) -> dict[str, Any]:
    """A daemon run's misses against the trace of its CPU: each COMMAND_LATE on tick k+1 is the window from SAMPLE k
    to tick k+1; a jump of the device's clock (hil-mock's skipped periods) is the window it jumped; device time is
    mapped onto the monotonic clock by hil-mock's ``clock_origin_s``."""
    from firmware_protocol import StatusFlags
    from furuta_rt.io.mcap_read import read_log

    ticks = read_log(log_path, timing=False, events=False).ticks
    t = clock_origin_s + np.asarray(ticks["t"], dtype=float)
    late = np.flatnonzero((np.asarray(ticks["status"]) & int(StatusFlags.COMMAND_LATE))[1:] != 0)
    skipped = np.flatnonzero(np.diff(t) > 1.5 / rate)
    timeline = read_timeline(trace_path, cpu)
    windows = [(t[k], t[k + 1], 1) for k in late] + [(t[k], t[k + 1], round((t[k + 1] - t[k]) * rate) - 1) for k in skipped]
    out = attribute_windows(windows, timeline, 1.0 / rate)
    return out | timeline_figures(timeline, (t[0], t[-1]) if len(t) else (0.0, 0.0))
