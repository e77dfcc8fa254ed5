"""Signals for the diagnosis: the rig's states reconstructed from a recording, all seen through ONE
smoothing filter so that both sides of eq. 4 are filtered alike.

Every signal is convolved with the same Gaussian G_σ (and its derivatives G', G'', G'''), so
G*φ̈ = G''*φ exactly and the applied torque is G*τ. The inverse-dynamics residual of eq. 4 computed
from the filtered states is then the filtered residual of the true states (exactly for the terms that
are linear in the states — M(θ) q̈ near upright, gravity, the input — and to second order for the
rest).

Measurement path (thesis section 3.3, appendix B): θ_f = H θ with H = a0/(s² + a1 s + a0), so

    θ = θ_f + (a1/a0)·θ̇_f + θ̈_f/a0,

and the derivatives follow from θ̇_f (the filter's differentiator output) by the same relation.
The command logged at tick k acts during [t_k + D·h, t_k + (D+1)·h) (D = command_delay_ticks); its
filtered value is an exact sum of Gaussian integrals over those hold intervals, so an extra actuator
delay d is a continuous parameter.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from furuta_rt.config import RigConfig
from furuta_rt.errors import UserError
from furuta_rt.model.sensors import BesselPath
from furuta_rt.recording import Recording


@dataclass(frozen=True)
class GaussianFilter:
    """Gaussian smoothing of width σ on a uniform grid of step dt, with consistent derivatives.

    Derivatives are finite differences smoothed by the sampled Gaussian g. The second difference is
    exact for a signal driven by a held input: (x_{k+1} − 2x_k + x_{k−1})/dt² = ∫Λ(t_k − s) ẍ(s) ds,
    Λ the unit-area triangle of half-width dt. So every filtered quantity is the continuous signal
    seen through the one kernel K = Σ_j g_j Λ(· − τ_j) (piecewise linear), and the held command is
    integrated through K exactly.
    """

    sigma: float
    dt: float
    kernels: tuple[np.ndarray, ...] = field(repr=False)

    @classmethod
    def build(cls, sigma: float, dt: float) -> GaussianFilter:
        half = math.ceil(4.5 * sigma / dt)
        tau = np.arange(-half, half + 1) * dt
        g = np.exp(-0.5 * (tau / sigma) ** 2)
        g /= g.sum()
        stencils = (
            np.array([1.0]),
            np.array([1.0, 0.0, -1.0]) / (2 * dt),
            np.array([1.0, -2.0, 1.0]) / dt**2,
            np.array([1.0, -2.0, 0.0, 2.0, -1.0]) / (2 * dt**3),
        )
        return cls(sigma, dt, tuple(np.convolve(g, s) for s in stencils))

    @property
    def weights(self) -> np.ndarray:
        return self.kernels[0]

    @property
    def half(self) -> int:
        return (len(self.kernels[0]) - 1) // 2

    def apply(self, x: np.ndarray, order: int = 0) -> np.ndarray:
        """K * x^(order) on the grid (edges, within `half` + 2 samples, are unreliable)."""
        return np.convolve(x, self.kernels[order], mode="same")

    def _cumulative(self, x: np.ndarray) -> np.ndarray:
        """∫_{−∞}^x K for the piecewise-linear K through (τ_j, g_j/dt), τ_j = j·dt, K = 0 beyond ±(half+1)·dt."""
        dt = self.dt
        nodes = np.concatenate([[0.0], self.weights / dt, [0.0]])  # at τ = (−half−1 … half+1)·dt
        areas = 0.5 * (nodes[:-1] + nodes[1:]) * dt
        cum = np.concatenate([[0.0], np.cumsum(areas)])
        pos = (x / dt) + self.half + 1  # in node units from the first node
        j = np.clip(np.floor(pos).astype(int), 0, len(nodes) - 2)
        s = np.clip(pos - j, 0.0, 1.0) * dt
        k0 = nodes[j]
        k1 = nodes[j + 1]
        out = cum[j] + k0 * s + (k1 - k0) * s * s / (2 * dt)
        out[pos <= 0] = 0.0
        out[pos >= len(nodes) - 1] = cum[-1]
        return out

    def hold_kernel(self, lag: float) -> tuple[int, np.ndarray]:
        """(m0, w) with (K * v)(t_i) = Σ_m w[m − m0] v_{i−m} for v_k held on [t_k + lag, t_k + lag + dt)."""
        dt = self.dt
        reach = (self.half + 1) * dt
        m0 = math.floor((lag - reach) / dt) - 1
        m1 = math.ceil((lag + dt + reach) / dt) + 1
        m = np.arange(m0, m1 + 1) * dt
        w = self._cumulative(m - lag) - self._cumulative(m - lag - dt)
        return m0, w

    def apply_held(self, v: np.ndarray, lag: float) -> np.ndarray:
        """K * (the zero-order-hold signal that takes value v_k on [t_k + lag, t_k + lag + dt))."""
        m0, w = self.hold_kernel(lag)
        full = np.convolve(v, w)
        n = len(v)
        idx = np.arange(n) - m0
        out = np.zeros(n)
        ok = (idx >= 0) & (idx < len(full))
        out[ok] = full[idx[ok]]
        return out


@dataclass
class States:
    """Filtered states and accelerations at one filter width (arrays on the recording's grid)."""

    theta: np.ndarray
    theta_dot: np.ndarray
    theta_ddot: np.ndarray
    phi: np.ndarray
    phi_dot: np.ndarray
    phi_ddot: np.ndarray
    filt: GaussianFilter

    def held(self, v: np.ndarray, lag: float) -> np.ndarray:
        return self.filt.apply_held(v, lag)

    def smooth(self, x: np.ndarray) -> np.ndarray:
        return self.filt.apply(x, 0)


@dataclass
class Prepared:
    """A recording on a uniform grid with what the diagnosis needs from the rig config."""

    t: np.ndarray
    theta_f: np.ndarray
    theta_dot_f: np.ndarray | None
    phi: np.ndarray
    u: np.ndarray
    dt: float
    bessel: BesselPath | None
    command_lag: float  # D·h: when the command of tick k starts acting, after its sample
    valid: np.ndarray  # samples far enough from the ends for the widest filter
    phi_lsb: float
    extra: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def n(self) -> int:
        return len(self.t)

    @property
    def commanded(self) -> bool:
        """Whether the recording has any nonzero command (else the command path cannot be assessed)."""
        return bool(np.any(self.u[self.valid] != 0))

    def moves(self, x: np.ndarray) -> bool:
        """Whether an angle travels at least MIN_TRAVEL_COUNTS encoder counts over the recording."""
        return float(np.ptp(x[self.valid])) >= MIN_TRAVEL_COUNTS * self.phi_lsb

    def states(self, sigma: float) -> States:
        """θ, φ and derivatives seen through G_σ, θ reconstructed through the inverse Bessel path."""
        f = GaussianFilter.build(sigma, self.dt)
        c1, c2 = 0.0, 0.0
        if self.bessel is not None:
            a1, a0 = self.bessel.coefficients()
            c1, c2 = a1 / a0, 1.0 / a0
        th = self.theta_f
        if self.theta_dot_f is not None:
            td = self.theta_dot_f
            d = [f.apply(td, k) for k in range(4)]  # G^(k) * θ̇_f
            theta = f.apply(th, 0) + c1 * d[0] + c2 * d[1]
            theta_dot = d[0] + c1 * d[1] + c2 * d[2]
            theta_ddot = d[1] + c1 * d[2] + c2 * d[3]
        else:
            d = [f.apply(th, k) for k in range(4)]
            theta = d[0] + c1 * d[1] + c2 * d[2]
            theta_dot = d[1] + c1 * d[2] + c2 * d[3]
            theta_ddot = d[2] + c1 * d[3] + c2 * np.gradient(d[3], self.dt)
        return States(
            theta=theta, theta_dot=theta_dot, theta_ddot=theta_ddot,
            phi=f.apply(self.phi, 0), phi_dot=f.apply(self.phi, 1), phi_ddot=f.apply(self.phi, 2), filt=f,
        )


MIN_TRAVEL_COUNTS = 50  # an angle that moves less than this is "still" for the diagnosis
MAX_SIGMA = 0.05  # s, widest filter the diagnosis uses (sets the margin at the ends)


def prepare(rec: Recording, rig: RigConfig, bessel_cutoff: float | str | None = "config") -> Prepared:
    """Check the recording and put it on a uniform grid at its median sample period."""
    n = len(rec)
    if n < 200:
        raise UserError(f"recording has {n} samples; the diagnosis needs at least 200 (a few seconds)")
    t = np.asarray(rec.t, dtype=float)
    dt = float(np.median(np.diff(t)))
    if not dt > 0:
        raise UserError("recording time stamps are not increasing")
    cols = {"theta": rec.theta, "phi": rec.phi, "u": rec.u}
    if rec.theta_dot is not None:
        cols["theta_dot"] = rec.theta_dot
    for name, v in cols.items():
        if not np.all(np.isfinite(v)):
            raise UserError(f"recording column {name!r} has non-finite values; clean or cut the recording first")
    jitter = float(np.max(np.abs(np.diff(t) - dt))) / dt
    if jitter > 0.05:  # resample onto a uniform grid (u held, the rest interpolated)
        grid = np.arange(t[0], t[-1], dt)
        idx = np.clip(np.searchsorted(t, grid, side="right") - 1, 0, n - 1)
        cols = {k: (v[idx] if k == "u" else np.interp(grid, t, v)) for k, v in cols.items()}
        t = grid
    cutoff = rig.sensors.bessel_cutoff if bessel_cutoff == "config" else bessel_cutoff
    margin = math.ceil(5 * MAX_SIGMA / dt) + 2
    valid = np.zeros(len(t), dtype=bool)
    valid[margin : len(t) - margin] = True
    if valid.sum() < 100:
        raise UserError(f"recording is {t[-1] - t[0]:.2f} s long; the diagnosis needs at least {2 * margin * dt + 1:.1f} s")
    return Prepared(
        t=t, theta_f=np.asarray(cols["theta"], float),
        theta_dot_f=None if "theta_dot" not in cols else np.asarray(cols["theta_dot"], float),
        phi=np.asarray(cols["phi"], float), u=np.asarray(cols["u"], float), dt=dt,
        bessel=BesselPath(cutoff) if cutoff else None,
        command_lag=rig.control.command_delay_ticks * dt, valid=valid,
        phi_lsb=2 * math.pi / rig.sensors.encoder_counts_per_rev,
        extra={k: np.asarray(v) for k, v in rec.extra.items() if len(v) == n and jitter <= 0.05},
    )
