"""Real-time pacing of the device loop and its timing statistics.

Deadlines are absolute (t0 + device clock), so errors never accumulate. Waiting is ``time.sleep``
to shortly before the deadline, then a busy wait. On this kind of box (Linux, 2 shared cores)
``time.sleep`` overshoots by ~90 µs median with the default 50 µs timer slack and by ~40 µs with the
slack set to 1 µs (done per thread with prctl); the busy wait follows the overshoot measured as the device
runs, up to ``spin_us`` (default 100 µs): the tick starts within a few µs of its deadline unless the
scheduler preempts the thread (then it is simply late).
"""

from __future__ import annotations

import ctypes
import os
import threading
import time
from dataclasses import dataclass, field

_PR_SET_TIMERSLACK = 29
LATENESS_BUCKETS_US = (25, 50, 100, 250, 500, 1000, 2000, 5000, 10_000)
SPIN_MARGIN_S = 5e-6


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


class DeadlineWaiter:
    """Return at (or just after) absolute deadlines: sleep to shortly before each, then spin.

    The spin lasts as long as this machine's sleeps overshoot now — their running mean (over ~32 wake-ups, each
    counted at most ``max_spin_s``) and half as much again — never more than ``max_spin_s``: the tick starts on
    time without burning the CPU a fixed long spin costs every period (a 100 µs spin is 10% of a core at 1 kHz,
    taken from the host it shares two CPUs with)."""

    __slots__ = ("max_spin_s", "overshoot_s")

    def __init__(self, max_spin_s: float) -> None:
        self.max_spin_s = max_spin_s
        self.overshoot_s = max_spin_s  # until measured: the configured spin

    @property
    def spin_s(self) -> float:
        """The spin before the next deadline."""
        return min(self.max_spin_s, 1.5 * self.overshoot_s + SPIN_MARGIN_S)

    def wait(self, deadline: float, spin: bool = True) -> None:
        """Return at ``deadline`` (perf_counter seconds); ``spin=False``: sleep to it (an idle device)."""
        pc = time.perf_counter
        wake = deadline - (self.spin_s if spin else 0.0)
        remaining = wake - pc()
        if remaining > 0:
            time.sleep(remaining)
            if spin:
                late = min(pc() - wake, self.max_spin_s)
                self.overshoot_s += (late - self.overshoot_s) * (1.0 / 32.0)
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
