"""Real-time pacing of the device loop and its timing statistics.

Deadlines are absolute (t0 + device clock), so errors never accumulate. Waiting is ``time.sleep``
to shortly before the deadline, then a busy wait. A sleep overshoots its wake-up time (tens of µs in a
VM even with the timer slack set to 1 µs, per thread with prctl, and erratically so on a loaded machine);
the busy wait follows the overshoot measured as the device runs, up to ``spin_us`` (default 100 µs), and
spins only where that buys on-time starts (DeadlineWaiter). A tick the scheduler delays beyond that is
simply late, and one a whole period late skips periods (counted as an overrun by the device).
"""

from __future__ import annotations

import ctypes
import os
import threading
import time
from bisect import bisect_right
from dataclasses import dataclass, field

_PR_SET_TIMERSLACK = 29
LATENESS_BUCKETS_US = (25, 50, 100, 250, 500, 1000, 2000, 5000, 10_000)
SPIN_MARGIN_S = 5e-6
FLOOR_Q = 0.1
"""The quantile of the sleeps' overshoot the busy wait covers (DeadlineWaiter)."""
QUANTILE_STEP_S = 2e-6
"""How far the quantile estimate moves per wake-up: to a 40-µs floor in ~0.2 s at 1 kHz, and within a few µs of the
quantile once there."""


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
    """Return at (or just after) absolute deadlines: sleep to shortly before each, then spin — only through the part of
    the sleep's overshoot that nearly every wake-up has.

    A sleep wakes late by an overshoot X that varies from wake-up to wake-up. Waking S early and spinning starts the
    tick on time whenever X ≤ S, at the CPU cost of S − X; when X > S the tick is late by X − S and the wait costs no
    spin at all. So S at a low quantile of X (``floor_s``, the 10th percentile of the recent overshoots, plus a margin;
    at most ``max_spin_s``) takes the steady part of the overshoot off every tick for almost no CPU, and a steady
    overshoot (a quiet machine) is covered outright. Spinning towards the erratic upper part would cost the CPU one
    for one — at SCHED_FIFO, where it also holds off the pty's kernel work on that CPU — for starts a few tens of µs
    earlier, which change neither the device's late ticks nor overruns nor the host's late commands."""

    __slots__ = ("floor_s", "max_spin_s")

    def __init__(self, max_spin_s: float) -> None:
        self.max_spin_s = max_spin_s
        self.floor_s = 0.0  # until measured: no spin

    @property
    def spin_s(self) -> float:
        """The spin before the next deadline."""
        return min(self.max_spin_s, self.floor_s + SPIN_MARGIN_S) if self.floor_s > 0.0 else 0.0

    def wait(self, deadline: float, spin: bool = True) -> None:
        """Return at ``deadline`` (perf_counter seconds); ``spin=False``: sleep to it (an idle device)."""
        pc = time.perf_counter
        if not spin or self.max_spin_s <= 0.0:
            remaining = deadline - pc()
            if remaining > 0:
                time.sleep(remaining)
            return
        wake = deadline - self.spin_s
        remaining = wake - pc()
        if remaining > 0:
            time.sleep(remaining)
            self.learn(pc() - wake)
        while pc() < deadline:
            pass

    def learn(self, overshoot: float) -> None:
        """One wake-up's overshoot into the floor (a stochastic-approximation quantile: it moves up FLOOR_Q of a step
        when the sample is above it, down the rest of a step when below, so it settles where FLOOR_Q of the samples
        fall below it)."""
        if overshoot < self.floor_s:
            self.floor_s -= QUANTILE_STEP_S * (1.0 - FLOOR_Q)
        else:
            self.floor_s += QUANTILE_STEP_S * FLOOR_Q


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
        self.histogram[bisect_right(LATENESS_BUCKETS_US, lateness * 1e6)] += 1

    def record_lockstep(self, ticks: int, sum_work: float, worst_work: float) -> None:
        """``ticks`` lockstep ticks at once (each on time: lateness 0), their work summed and its worst."""
        if ticks:
            self.ticks += ticks
            self.sum_work_s += sum_work
            if worst_work > self.worst_work_s:
                self.worst_work_s = worst_work
            self.histogram[bisect_right(LATENESS_BUCKETS_US, 0.0)] += ticks

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
