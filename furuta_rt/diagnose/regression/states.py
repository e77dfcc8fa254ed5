"""Signals for the diagnosis: the rig's states reconstructed from a recording, all seen through ONE
smoothing filter so that both sides of eq. 4 are filtered alike.

Every signal is convolved with the same kernel C (and its derivatives C', C'', C'''), so C*φ̈ = C''*φ
exactly and the applied torque is C*τ. C = K∘F: the equation's wide Gaussian K (30–50 ms, it removes
the encoder's quantisation noise) composed with a narrow one F (5 ms). The terms of eq. 4 that are
nonlinear in the states (M(θ) q̈, the Coriolis/centrifugal terms, gravity ε sin θ) are evaluated on the
lightly smoothed states F*x and the products filtered by K: K*f(F*x) = C*f(x) up to F's own small error
(of order σ_F²·ẋ²·f''/2), at any amplitude. Evaluated on the widely smoothed states instead,
f(C*x) ≠ C*f(x) once θ turns by more than a few degrees within the kernel (a swing-up): that biased
the inertias and invented springs. Terms linear in the states, the held command and the friction laws
evaluated on the instantaneous motion (encoder counts) are filtered by C directly, so every term of
eq. 4 is seen through the same C. F's noise (the encoder's quantisation through F's derivatives) enters
the products linearly, or as the square of a small velocity error, and is removed by K.

Angles (`canonical_angles`): θ is unwrapped and shifted by whole turns to a canonical range, φ by whole
turns so that the middle of its travel lies within ±π: the diagnosis does not depend on the encoder's
absolute turn count or on where a pendulum angle wraps.

Measurement path (thesis section 3.3, appendix B): θ_f = H θ with H = a0/(s² + a1 s + a0), so

    θ = θ_f + (a1/a0)·θ̇_f + θ̈_f/a0,

and the derivatives follow from θ̇_f (the filter's differentiator output) by the same relation.
The command logged at tick k acts during [t_k + D·h, t_k + (D+1)·h) (D = command_delay_ticks); its
filtered value is an exact sum of Gaussian integrals over those hold intervals, so an extra actuator
delay d is a continuous parameter.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

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
    def composed(cls, outer: GaussianFilter, inner: GaussianFilter) -> GaussianFilter:
        """outer∘inner: the kernel K*F (a Gaussian of width √(σ_K² + σ_F²) on the grid), the derivatives those
        of ``inner`` smoothed by ``outer`` (apply(x, k) = K*(F^(k)*x) exactly)."""
        return cls(math.hypot(outer.sigma, inner.sigma), outer.dt,
                   tuple(np.convolve(outer.kernels[0], k) for k in inner.kernels))

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
    def width(self) -> float:
        """√(second moment) of the smoothing kernel on the grid, s (≈ σ)."""
        w = self.weights
        tau = (np.arange(len(w)) - self.half) * self.dt
        return float(np.sqrt(np.sum(w * tau**2)))

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
    """Filtered states and accelerations at one filter width (arrays on the recording's grid).

    With ``fine`` (the states seen through a narrow kernel F) these are seen through C = K∘F and ``outer``
    is K: a nonlinear function of the states is evaluated on ``base`` (= ``fine``) and filtered by
    ``product`` (K); a function of the instantaneous motion (encoder counts) by ``smooth`` (C)."""

    theta: np.ndarray
    theta_dot: np.ndarray
    theta_ddot: np.ndarray
    phi: np.ndarray
    phi_dot: np.ndarray
    phi_ddot: np.ndarray
    filt: GaussianFilter
    outer: GaussianFilter | None = None
    fine: States | None = None
    # the window stages' arm simulations from these states (stickslip.window_errors), kept for the diagnosis
    simulations: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def base(self) -> States:
        """The states a nonlinear term is evaluated on (``fine``, or these when there is none)."""
        return self.fine if self.fine is not None else self

    def held(self, v: np.ndarray, lag: float) -> np.ndarray:
        return self.filt.apply_held(v, lag)

    def smooth(self, x: np.ndarray) -> np.ndarray:
        """C * x: x a function of the instantaneous motion or of the raw signals."""
        return self.filt.apply(x, 0)

    def product(self, x: np.ndarray) -> np.ndarray:
        """K * x: x a function evaluated on ``base`` (C * the function of the true states, up to F's error)."""
        return (self.outer or self.filt).apply(x, 0)


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
    notes: list[str] = field(default_factory=list)  # what prepare() repaired (gaps filled, samples merged, resampled)
    turns: tuple[float, float] = (0.0, 0.0)  # what canonical_angles took from (θ, φ) (rad, whole turns)

    def as_recorded(self) -> Prepared:
        """These signals with the angles as recorded (the whole turns canonical_angles removed put back): for checks
        of the recording's units, where θ = 180 means something."""
        return replace(self, theta_f=self.theta_f + self.turns[0], phi=self.phi + self.turns[1], turns=(0.0, 0.0))

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

    def states(self, sigma: float, fine: States | None = None) -> States:
        """θ, φ and derivatives seen through G_σ (G_σ∘F with ``fine`` seen through F: see States), θ
        reconstructed through the inverse Bessel path."""
        outer = GaussianFilter.build(sigma, self.dt)
        if fine is None:
            return self._states(outer)
        s = self._states(GaussianFilter.composed(outer, fine.filt))
        s.outer, s.fine = outer, fine
        return s

    def _states(self, f: GaussianFilter) -> States:
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


def canonical_angles(theta: np.ndarray, phi: np.ndarray, keep_phi: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(θ, φ) made independent of where the angles wrap and of the encoders' absolute turn counts.

    θ is unwrapped (a pendulum angle that wraps at ±π becomes continuous) and shifted by whole turns so
    that its median lies in [−π, π] when the pendulum is mostly up (cos > 0), in [0, 2π) when it mostly
    hangs (so that neither case sits on the boundary). φ is shifted by whole turns so that the middle of its
    travel lies in [−π, π] — unless ``keep_phi`` (the rig's config declares a cable spring, whose rest angle
    is then given in the encoder's own turns). Eq. 4 is 2π-periodic in θ and independent of φ; only a spring
    depends on φ itself."""
    theta = np.unwrap(np.asarray(theta, dtype=float))
    m = float(np.median(theta))
    turns = round(m / (2 * math.pi)) if math.cos(m) > 0 else math.floor(m / (2 * math.pi))
    theta = theta - 2 * math.pi * turns if turns else theta
    phi = np.asarray(phi, dtype=float)
    if not keep_phi:
        shift = round(0.5 * (float(np.max(phi)) + float(np.min(phi))) / (2 * math.pi))
        phi = phi - 2 * math.pi * shift if shift else phi
    return theta, phi


MIN_TRAVEL_COUNTS = 50  # an angle that moves less than this is "still" for the diagnosis
MAX_SIGMA = 0.05  # s, widest filter the diagnosis uses (sets the margin at the ends)


MIN_SECONDS = 2.0  # a shorter recording is refused
MIN_SAMPLES = 100  # ... and one of fewer samples: 2 s at the 50 Hz hobby and teaching rigs log
MIN_VALID = 50  # samples clear of the widest kernel at both ends
MAX_MISSING_SHARE = 0.05  # more non-finite samples than this share of a column: refused
MAX_GAP_SECONDS = 0.05  # a longer run of non-finite samples (or of missing time) is refused


def edge_margin(dt: float) -> int:
    """Samples at each end of a stretch within reach of the widest kernel (MAX_SIGMA): not valid rows."""
    return math.ceil(5 * MAX_SIGMA / dt) + 2


def long_enough(n: int, dt: float) -> bool:
    """Whether a stretch of ``n`` samples at period ``dt`` is one prepare() accepts (samples, seconds, valid rows)."""
    return n >= MIN_SAMPLES and (n - 1) * dt >= MIN_SECONDS and n - 2 * edge_margin(dt) >= MIN_VALID


def _gaps(bad: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) index ranges of the runs of True in ``bad``."""
    edges = np.diff(np.concatenate([[0], bad.astype(int), [0]]))
    return list(zip(np.flatnonzero(edges == 1).tolist(), np.flatnonzero(edges == -1).tolist(), strict=True))


def _repair(t: np.ndarray, cols: dict[str, np.ndarray], notes: list[str]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Rows without a time dropped, repeated time stamps merged (the last sample kept), short runs of missing
    samples filled (angles linearly, the command held); too much missing is a UserError."""
    keep = np.isfinite(t)
    if not keep.all():
        notes.append(f"{int((~keep).sum())} rows without a finite time stamp were dropped")
        t, cols = t[keep], {k: v[keep] for k, v in cols.items()}
    if len(t) > 1 and np.any(np.diff(t) < 0):
        i = int(np.argmax(np.diff(t) < 0))
        raise UserError(f"the time stamps go backwards at t = {t[i]:.4g} s (to {t[i + 1]:.4g} s): is it several recordings "
                        "joined? cut it into its parts")
    last = np.concatenate([np.diff(t) > 0, [True]])  # the last of each run of equal time stamps
    if not last.all():
        notes.append(f"{int((~last).sum())} repeated time stamps: the last sample of each was kept")
        t, cols = t[last], {k: v[last] for k, v in cols.items()}
    n = len(t)
    for name, v in cols.items():
        bad = ~np.isfinite(v)
        if not bad.any():
            continue
        runs = _gaps(bad)
        longest = max(t[min(b, n - 1)] - t[max(a - 1, 0)] for a, b in runs)
        if bad.mean() > MAX_MISSING_SHARE or longest > MAX_GAP_SECONDS or bad.all():
            raise UserError(f"recording column {name!r} has {int(bad.sum())} non-finite values of {n} (longest gap "
                            f"{longest:.3g} s); the diagnosis fills gaps up to {MAX_GAP_SECONDS * 1e3:.0f} ms and "
                            f"{100 * MAX_MISSING_SHARE:.0f} % of the samples: cut the recording or clean it")
        ok = ~bad
        if name == "u":  # held: the last finite command (the first finite one before it)
            idx = np.maximum.accumulate(np.where(ok, np.arange(n), -1))
            filled = v[np.where(idx >= 0, idx, int(np.argmax(ok)))]
        else:
            filled = np.interp(t, t[ok], v[ok])
        cols[name] = filled
        notes.append(f"column {name!r}: {int(bad.sum())} non-finite samples in {len(runs)} gap(s) filled "
                     + ("(held)" if name == "u" else "(linear interpolation)"))
    return t, cols


def prepare(rec: Recording, rig: RigConfig, bessel_cutoff: float | str | None = "config") -> Prepared:
    """Check the recording, repair what can be repaired (saying so in ``notes``), and put it on a uniform grid at
    its median sample period. Anything that cannot be diagnosed is a one-line UserError."""
    notes: list[str] = []
    n = len(rec)
    if n < MIN_SAMPLES:
        raise UserError(f"recording has {n} samples; the diagnosis needs at least {MIN_SAMPLES} (a few seconds)")
    cols = {"theta": rec.theta, "phi": rec.phi, "u": rec.u}
    if rec.theta_dot is not None:
        cols["theta_dot"] = rec.theta_dot
    cols = {k: np.asarray(v, dtype=float) for k, v in cols.items()}
    t, cols = _repair(np.asarray(rec.t, dtype=float), cols, notes)
    # before any resampling (an interpolation across a wrap of θ would be wrong)
    raw = cols["theta"], cols["phi"]
    cols["theta"], cols["phi"] = canonical_angles(*raw, keep_phi=rig.effects.arm_spring is not None)
    turns = (float(np.median(raw[0] - cols["theta"])), float(np.median(raw[1] - cols["phi"])))
    if len(t) < MIN_SAMPLES:
        raise UserError(f"recording has {len(t)} usable samples; the diagnosis needs at least {MIN_SAMPLES} (a few seconds)")
    steps = np.diff(t)
    dt = float(np.median(steps))
    if not dt > 0:
        raise UserError("recording time stamps are not increasing")
    if t[-1] - t[0] < MIN_SECONDS:
        raise UserError(f"recording is {t[-1] - t[0]:.2f} s long; the diagnosis needs at least {MIN_SECONDS:.0f} s")
    holes = np.flatnonzero(steps > MAX_GAP_SECONDS + 1.5 * dt)
    if len(holes):
        i = int(holes[np.argmax(steps[holes])])
        raise UserError(f"recording has {len(holes)} gap(s) in time, the longest {steps[i]:.3g} s at t = {t[i]:.4g} s; "
                        f"one stretch bridges at most {MAX_GAP_SECONDS * 1e3:.0f} ms: diagnose it with "
                        "furuta_rt.diagnose.diagnose_recording (as the CLI does), which splits it at its gaps")
    jitter = float(np.max(np.abs(steps - dt))) / dt
    resampled = jitter > 0.05
    if resampled:  # resample onto a uniform grid (u held, the rest interpolated)
        grid = np.arange(t[0], t[-1], dt)
        idx = np.clip(np.searchsorted(t, grid, side="right") - 1, 0, len(t) - 1)
        cols = {k: (v[idx] if k == "u" else np.interp(grid, t, v)) for k, v in cols.items()}
        notes.append(f"irregular sample times (up to {100 * jitter:.0f} % off the median period {1e3 * dt:.3g} ms): "
                     "resampled onto a uniform grid (angles interpolated, the command held)")
        t = grid
    cutoff = rig.sensors.bessel_cutoff if bessel_cutoff == "config" else bessel_cutoff
    margin = edge_margin(dt)
    valid = np.zeros(len(t), dtype=bool)
    valid[margin : len(t) - margin] = True
    if valid.sum() < MIN_VALID:
        raise UserError(f"recording is {t[-1] - t[0]:.2f} s long; the diagnosis needs at least "
                        f"{(2 * margin + MIN_VALID) * dt:.2g} s at its {1 / dt:.0f} Hz")
    same = len(t) == n and not resampled
    return Prepared(
        t=t, theta_f=cols["theta"], theta_dot_f=cols.get("theta_dot"), phi=cols["phi"], u=cols["u"], dt=dt,
        bessel=BesselPath(cutoff) if cutoff else None,
        command_lag=rig.control.command_delay_ticks * dt, valid=valid,
        phi_lsb=2 * math.pi / rig.sensors.encoder_counts_per_rev,
        extra={k: np.asarray(v) for k, v in rec.extra.items() if len(v) == n and same},
        notes=notes, turns=turns,
    )
