"""Real-time pacing of the device loop and its timing statistics.

Deadlines are absolute (t0 + device clock), so errors never accumulate. Waiting is ``time.sleep``
up to ``spin_us`` before the deadline, then a busy wait. On this kind of box (Linux, 2 shared cores)
``time.sleep`` overshoots by ~90 µs median with the default 50 µs timer slack and by ~40 µs with the
slack set to 1 µs (done per thread with prctl), hence the 100 µs default spin: the tick starts within a
few µs of its deadline unless the scheduler preempts the thread (then it is simply late).
"""

from __future__ import annotations

import ctypes
import os
import threading
import time
from dataclasses import dataclass, field

_PR_SET_TIMERSLACK = 29
LATENESS_BUCKETS_US = (25, 50, 100, 250, 500, 1000, 2000, 5000, 10_000)


def set_timer_slack(ns: int = 1000) -> bool:
    """Tighten the calling thread's timer slack (Linux); False where unavailable."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(_PR_SET_TIMERSLACK, ns, 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def raise_priority(rt_priority: int = 10) -> str:
    """Give the calling thread SCHED_FIFO at ``rt_priority`` (Linux, needs CAP_SYS_NICE), else try
    nice −10; returns what was obtained ("fifo", "nice" or "normal"). The device thread sleeps
    most of each period, so real-time priority costs others nothing but removes scheduling delays."""
    try:
        policy = os.SCHED_FIFO | getattr(os, "SCHED_RESET_ON_FORK", 0)  # children start at normal priority
        os.sched_setscheduler(0, policy, os.sched_param(rt_priority))
        return "fifo"
    except (OSError, AttributeError):
        pass
    try:
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), -10)
        return "nice"
    except (OSError, AttributeError):
        return "normal"


def wait_until(deadline: float, spin_s: float) -> None:
    """Return at (or just after) ``deadline`` (perf_counter seconds)."""
    pc = time.perf_counter
    remaining = deadline - pc() - spin_s
    if remaining > 0:
        time.sleep(remaining)
    while pc() < deadline:
        pass


@dataclass(slots=True)
class TickTiming:
    """Lateness of tick starts w.r.t. their deadlines, and the work time of each tick."""

    late_threshold_s: float
    ticks: int = 0
    late_ticks: int = 0
    overruns: int = 0  # ticks that started a whole period or more late (periods skipped)
    missed_periods: int = 0
    worst_lateness_s: float = 0.0
    sum_lateness_s: float = 0.0
    worst_work_s: float = 0.0
    sum_work_s: float = 0.0
    histogram: list[int] = field(default_factory=lambda: [0] * (len(LATENESS_BUCKETS_US) + 1))

    def record(self, lateness: float, work: float) -> None:
        self.ticks += 1
        self.sum_lateness_s += lateness
        self.sum_work_s += work
        if lateness > self.worst_lateness_s:
            self.worst_lateness_s = lateness
        if work > self.worst_work_s:
            self.worst_work_s = work
        if lateness > self.late_threshold_s:
            self.late_ticks += 1
        us = lateness * 1e6
        i = 0
        for edge in LATENESS_BUCKETS_US:
            if us < edge:
                break
            i += 1
        self.histogram[i] += 1

    def percentile_us(self, q: float) -> float:
        """Upper edge (µs) of the histogram bucket holding the q-quantile of lateness (inf if beyond)."""
        if not self.ticks:
            return 0.0
        target = q * self.ticks
        count = 0
        for i, n in enumerate(self.histogram):
            count += n
            if count >= target:
                return float(LATENESS_BUCKETS_US[i]) if i < len(LATENESS_BUCKETS_US) else float("inf")
        return float("inf")
