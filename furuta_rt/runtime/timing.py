"""Timing accounting of the control loop: device clock, O(1) histograms, running statistics.

Everything here runs every tick inside the control process, so it is plain Python on ints and floats: a
histogram counts 1 µs bins. The loop appends a tick's timings to each histogram's ``pending`` list (a C
call) and bins them in batches (``fold``: C loops) after the command is out.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass

_WRAP_US = 1 << 32


class DeviceClock:
    """Unwraps the SAMPLE's u32 µs timestamp and maps device time onto the host clock.

    The host time of a sample's tick is estimated as ``t_dev + offset`` where ``offset`` tracks the
    minimum of (host receive time − device time): the least-delayed sample sets it. The minimum leaks
    upward by ``drift_ppm`` so a device crystal slower than the host clock is followed too.
    """

    __slots__ = ("_last_raw", "_last_us", "_prev_dev_ns", "drift_ppm", "offset_ns")

    def __init__(self, drift_ppm: float = 200.0) -> None:
        self._last_raw: int | None = None
        self._last_us = 0
        self._prev_dev_ns = 0
        self.offset_ns: int | None = None
        self.drift_ppm = drift_ppm

    def unwrap(self, t_us: int) -> int:
        """Device time in µs, monotonic across the 71.6-minute wrap of the u32 counter."""
        if self._last_raw is None:
            self._last_raw = t_us
            self._last_us = t_us
            return t_us
        delta = (t_us - self._last_raw) % _WRAP_US
        if delta > _WRAP_US // 2:  # a step backwards (reordered or reset device): keep it signed
            delta -= _WRAP_US
        self._last_raw = t_us
        self._last_us += delta
        return self._last_us

    def observe(self, dev_us: int, host_ns: int) -> int:
        """Feed one (device µs, host receive ns) pair; returns the estimated host ns of the device tick."""
        dev_ns = dev_us * 1000
        off = host_ns - dev_ns
        cur = self.offset_ns
        if cur is None or off < cur:
            cur = off
        else:  # leak toward later offsets (a device clock slower than the host's), at most drift_ppm
            cur = min(off, cur + int((dev_ns - self._prev_dev_ns) * self.drift_ppm * 1e-6))
        self.offset_ns = cur
        self._prev_dev_ns = dev_ns
        return dev_ns + cur


class Histogram:
    """Counts of non-negative values in 1-unit bins up to ``size``; larger values fall in the last bin.

    ``max``/``min``/``mean`` are exact; percentiles are exact to one bin below the overflow bin. The loop appends
    a tick's value to ``pending`` (one C call) and ``fold`` bins a batch of them in C loops (a Counter of the
    bins in use); every reader below folds first.
    """

    __slots__ = ("_count", "_max", "_min", "_total", "bins", "pending", "size")

    def __init__(self, size: int = 20_000) -> None:
        self.size = size
        self.bins: Counter[int] = Counter()  # bin → count, bins 0..size only
        self._count = 0
        self._total = 0.0
        self._max = -math.inf
        self._min = math.inf
        self.pending: list[float] = []

    def add(self, value: float) -> None:
        self.pending.append(value)
        self.fold()

    def fold(self) -> None:
        """Bin the values waiting in ``pending`` and empty it (the same list: the loop holds its ``append``)."""
        values = self.pending
        if not values:
            return
        bins = self.bins
        bins.update(map(int, values))
        self._count += len(values)
        self._total += sum(values)
        hi, lo = max(values), min(values)
        if hi > self._max:
            self._max = hi
        if lo < self._min:
            self._min = lo
        size = self.size
        if hi >= size + 1 or lo < 0:  # rare: out-of-range values into the first and the last bin
            for i in {int(v) for v in values if not 0 <= v < size + 1}:
                if i < 0 or i > size:
                    bins[0 if i < 0 else size] += bins.pop(i)
        values.clear()

    @property
    def count(self) -> int:
        self.fold()
        return self._count

    @property
    def total(self) -> float:
        self.fold()
        return self._total

    @property
    def max(self) -> float:
        self.fold()
        return self._max

    @property
    def min(self) -> float:
        self.fold()
        return self._min

    def percentile(self, q: float) -> float:
        """Value below which a fraction ``q`` (0..1) of the samples lie (bin upper edge), NaN if empty."""
        count = self.count
        if count == 0:
            return math.nan
        target = q * count
        acc = 0
        for i in sorted(self.bins):
            c = self.bins[i]
            acc += c
            if acc >= target and c:
                return min(float(i + 1), self._max) if i < self.size else self._max
        return self._max

    @property
    def mean(self) -> float:
        count = self.count
        return self._total / count if count else math.nan

    def summary(self) -> dict[str, float]:
        count = self.count
        return {"p50": self.percentile(0.5), "p99": self.percentile(0.99), "max": self._max if count else math.nan,
                "mean": self.mean}


class RunningStats:
    """Welford mean and standard deviation."""

    __slots__ = ("m2", "mean", "n")

    def __init__(self) -> None:
        self.n = 0
        self.mean = 0.0
        self.m2 = 0.0

    def add(self, x: float) -> None:
        self.n += 1
        d = x - self.mean
        self.mean += d / self.n
        self.m2 += d * (x - self.mean)

    @property
    def std(self) -> float:
        return math.sqrt(self.m2 / self.n) if self.n > 1 else math.nan


@dataclass
class Window:
    """Loop rate and jitter over the last dashboard window (reset by the reader)."""

    ticks: int = 0
    start_ns: int = 0
    max_dev_us: float = 0.0

    def add(self, dev_us: float) -> None:
        self.ticks += 1
        if dev_us > self.max_dev_us:
            self.max_dev_us = dev_us
