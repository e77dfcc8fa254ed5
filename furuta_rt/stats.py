"""Summary statistics of a recording: spread of θ, φ, u and the limit cycle when there is one.

Friction on the arm makes the balanced pendulum oscillate (thesis sections 5-6): a limit cycle in φ
(and θ) whose amplitude and period the compensation is meant to reduce. ``limit_cycle_stats`` finds
such an oscillation with a Schmitt trigger (hysteresis at ±30 % of the signal's spread, so sensor noise
does not count as crossings) and reports it only when it is clearly periodic.
"""

from __future__ import annotations

import itertools
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from furuta_rt.recording import Recording

MIN_CYCLES = 3
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


def _upward_crossings(x: np.ndarray, band: float) -> np.ndarray:
    """Indices where x rises through +band having last been below −band (Schmitt trigger)."""
    above, below = x > band, x < -band
    out = []
    armed = False
    events = np.flatnonzero(above | below)
    for i in events:
        if below[i]:
            armed = True
        elif armed:
            out.append(i)
            armed = False
    return np.asarray(out, dtype=int)


def limit_cycle_stats(t: np.ndarray, x: np.ndarray) -> LimitCycle | None:
    """The dominant oscillation of x(t), or None when there is no clear one (fewer than three regular
    cycles, or a weak autocorrelation at the period)."""
    t = np.asarray(t, dtype=float)
    x = np.asarray(x, dtype=float)
    ok = np.isfinite(x) & np.isfinite(t)
    t, x = t[ok], x[ok]
    if len(x) < 16:
        return None
    # remove a linear drift so a slowly walking arm still shows its oscillation
    x = x - np.polyval(np.polyfit(t - t[0], x, 1), t - t[0])
    spread = float(np.std(x))
    if spread == 0.0:
        return None
    up = _upward_crossings(x, 0.3 * spread)
    if len(up) < MIN_CYCLES + 1:
        return None
    periods = np.diff(t[up])
    mean = float(np.mean(periods))
    period_spread = float(np.std(periods) / mean)
    if period_spread > MAX_PERIOD_SPREAD:
        return None
    period = float(np.median(periods))
    dt = float(np.median(np.diff(t)))
    # peak-to-peak of x smoothed over 1/20 period: the oscillation's, not the sensor noise's
    w = max(1, round(period / (20 * dt)))
    xs = np.convolve(x, np.ones(w) / w, mode="same")
    ptp = np.array([np.ptp(xs[a:b]) for a, b in itertools.pairwise(up)])
    lag = round(period / dt)
    if lag <= 0 or lag >= len(x):
        return None
    ac = float(np.dot(x[:-lag], x[lag:]) / np.sqrt(np.dot(x[:-lag], x[:-lag]) * np.dot(x[lag:], x[lag:])))
    if ac < MIN_AUTOCORRELATION:
        return None
    p2p = float(np.median(ptp))
    return LimitCycle(period, 0.5 * p2p, p2p, len(periods), period_spread, ac)


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
