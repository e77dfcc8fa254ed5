"""Summary statistics of a recording: spread of θ, φ, u and the limit cycle when there is one.

Friction on the arm makes the balanced pendulum oscillate (thesis sections 5-6): a limit cycle in φ
(and θ) whose amplitude and period the compensation is meant to reduce. ``limit_cycle_stats`` finds
such an oscillation with a Schmitt trigger (hysteresis at ±30 % of the signal's spread, so sensor noise
does not count as crossings) and reports it only when it is clearly periodic. Rising and falling
crossings both time the period (rising → rising, falling → falling), so two cycles are enough: a
10 s log of the thesis' Coulomb limit cycle (period ~4 s) holds two. The same function serves the run
summary, the dashboard and ``replay``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from furuta_rt.recording import Recording

MIN_CYCLES = 2  # period measurements (rising→rising or falling→falling): two cycles
MAX_PERIOD_SPREAD = 0.25  # std/mean of the cycle periods for "clearly periodic"
MIN_AUTOCORRELATION = 0.5  # normalised autocorrelation at one period


@dataclass(frozen=True)
class LimitCycle:
    period: float  # s, median of the cycle periods
    amplitude: float  # half the median peak-to-peak of the cycles (same unit as x)
    peak_to_peak: float
    cycles: int
    period_spread: float  # std/mean of the cycle periods
    autocorrelation: float  # normalised autocorrelation at the period lag

    @property
    def frequency(self) -> float:
        return 1.0 / self.period


def _crossings(x: np.ndarray, band: float) -> np.ndarray:
    """Indices where x passes from below −band to above +band or back (a Schmitt trigger): rising and
    falling crossings alternate."""
    side = np.zeros(len(x), dtype=np.int8)
    side[x > band] = 1
    side[x < -band] = -1
    idx = np.flatnonzero(side)
    if len(idx) == 0:
        return idx
    s = side[idx]
    change = np.flatnonzero(s[1:] != s[:-1]) + 1  # first sample on the other side
    return idx[change]


def _autocorrelation(x: np.ndarray, lag: int) -> float:
    """Normalised correlation of x with itself ``lag`` samples later."""
    a, b = x[:-lag], x[lag:]
    return float(np.dot(a, b) / np.sqrt(np.dot(a, a) * np.dot(b, b)))


def limit_cycle_stats(t: np.ndarray, x: np.ndarray) -> LimitCycle | None:
    """The dominant oscillation of x(t), or None when there is no clear one (fewer than two regular
    cycles, or a weak autocorrelation at the period)."""
    t = np.asarray(t, dtype=float)
    x = np.asarray(x, dtype=float)
    ok = np.isfinite(x) & np.isfinite(t)
    t, x = t[ok], x[ok]
    if len(x) < 16:
        return None
    # remove a linear drift so a slowly walking arm still shows its oscillation: the line through the means
    # of x over its first and its last whole period (a line fitted to all of x would be tilted by the part
    # cycles at the ends when there are only a few)
    x = x - np.polyval(np.polyfit(t - t[0], x, 1), t - t[0])
    for refine in range(3):
        spread = float(np.std(x))
        if spread == 0.0:
            return None
        cross = _crossings(x, 0.3 * spread)
        if len(cross) < MIN_CYCLES + 2:  # rising, falling, rising, falling: one period each way
            return None
        if refine == 2:
            break
        a0, a1, b0, b1 = cross[0], cross[2], cross[-3], cross[-1]
        ta, tb = np.mean(t[a0:a1]), np.mean(t[b0:b1])
        slope = (np.mean(x[b0:b1]) - np.mean(x[a0:a1])) / (tb - ta) if tb > ta else 0.0
        x = x - (np.mean(x[a0:a1]) + slope * (t - ta))
    tc = t[cross]
    periods = tc[2:] - tc[:-2]  # rising→rising and falling→falling, interleaved
    mean = float(np.mean(periods))
    period_spread = float(np.std(periods) / mean)
    if period_spread > MAX_PERIOD_SPREAD:
        return None
    period = float(np.median(periods))
    dt = float(np.median(np.diff(t)))
    # peak-to-peak of x smoothed over 1/20 period: the oscillation's, not the sensor noise's
    w = max(1, round(period / (20 * dt)))
    xs = np.convolve(x, np.ones(w) / w, mode="same")
    ptp = np.array([np.ptp(xs[a:b]) for a, b in zip(cross[:-2], cross[2:], strict=True)])
    lag = round(period / dt)
    if lag <= 1 or lag >= len(x):
        return None
    ac = _autocorrelation(x, lag)
    # an oscillation is also in anti-phase with itself half a period on; a wandering (smooth random) signal
    # that happened to cross the bands at regular times is not: it still resembles itself half a period on
    if ac < MIN_AUTOCORRELATION or _autocorrelation(x, lag // 2) > -MIN_AUTOCORRELATION:
        return None
    p2p = float(np.median(ptp))
    cycles = len(cross) // 2  # a rising and a falling crossing per cycle seen
    return LimitCycle(period, 0.5 * p2p, p2p, cycles, period_spread, ac)


def summary_stats(rec: Recording, start: float | None = None) -> dict[str, Any]:
    """Means, standard deviations and ranges of θ, φ, u (from time ``start`` on, default: all), and the
    limit cycle of φ and of θ (None when there is none)."""
    sel = slice(None) if start is None else rec.t >= start
    t = rec.t[sel]
    out: dict[str, Any] = {"duration": float(t[-1] - t[0]) if len(t) > 1 else 0.0, "samples": len(t)}
    for name in ("theta", "phi", "u"):
        v = getattr(rec, name)[sel]
        out[name] = {
            "mean": float(np.mean(v)), "std": float(np.std(v)), "min": float(np.min(v)), "max": float(np.max(v)),
        } if len(v) else None
    for name in ("phi", "theta"):
        lc = limit_cycle_stats(t, getattr(rec, name)[sel])
        out[f"limit_cycle_{name}"] = asdict(lc) if lc is not None else None
    return out
