"""Describing-function analysis of the friction limit cycle, thesis section 4 (eq. 8–11, figure 9).

With u = L·x + F (eq. 5 plus the arm friction torque F), the linearised plant (eq. 6) gives

    φ̇ = G(s)·F,   G(s) = C (sI − A − B L)⁻¹ B,   C = [0 0 0 1],

built here from FurutaPlant.linearize() with python-control (no α…ε formulas typed twice). Coulomb
friction opposes motion, F = −Fc·sgn(φ̇), so the loop is G in negative feedback with the relay
N(φ̇) = Fc·sgn(φ̇), whose describing function is 4Fc/(πC) for a sine of amplitude C. A limit cycle is
predicted where G(jω) = −1/N(C) = −πC/(4Fc): where G crosses the negative real axis, at ω0 with
φ̇ amplitude C = 4Fc·|G(jω0)|/π. Whether that oscillation is stable follows from the Loeb criterion
(does a slightly larger amplitude decay?), checked on the roots of den(s) + k·num(s) around k = N(C).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import control
import numpy as np
from scipy.optimize import brentq

from furuta_rt.config import ActuatorConfig, RigConfig
from furuta_rt.controller.design import actuated_linearization
from furuta_rt.controller.loop_analysis import loop_model
from furuta_rt.model.plant import FurutaPlant

# The four feedbacks of thesis section 4 and the thesis' conclusion (limit cycle or not).
SECTION4_CASES: dict[str, tuple[tuple[float, float, float, float], bool]] = {
    "60θ+20θ̇+10φ+4φ̇ (4.1)": ((60.0, 20.0, 10.0, 4.0), True),
    "60θ+20θ̇ (4.2)": ((60.0, 20.0, 0.0, 0.0), False),
    "60θ+20θ̇+φ̇ (4.3)": ((60.0, 20.0, 0.0, 1.0), False),
    "60θ+20θ̇+7φ̇ (4.3)": ((60.0, 20.0, 0.0, 7.0), True),
}


class CoulombRelay(control.DescribingFunctionNonlinearity):
    """The friction nonlinearity seen by the loop, N(v) = Fc·sgn(v) (the torque is −N), with the
    describing function 4Fc/(πC) of an ideal relay."""

    def __init__(self, fc: float) -> None:
        super().__init__()
        if fc < 0:
            raise ValueError(f"Coulomb level Fc must be >= 0, got {fc}")
        self.fc = float(fc)

    def __call__(self, x: float) -> float:
        return self.fc * float(np.sign(x))

    def _isstatic(self) -> bool:
        return True

    def describing_function(self, A: float) -> complex:
        if A <= 0:
            raise ValueError("the describing function needs an amplitude > 0")
        return 4.0 * self.fc / (math.pi * A) + 0j


def closed_loop_ss(
    plant: FurutaPlant, gains: np.ndarray | list[float], actuator: ActuatorConfig | None = None
) -> control.StateSpace:
    """ẋ = (A + B L) x + B_F F with all four states as outputs (eq. 6 with u = L·x + F).

    For a torque actuator B_F = B. For a voltage-driven DC motor (``actuator``) the command enters
    through the motor (back-EMF in A, B scaled by Kt/R) while the friction torque still enters as a
    torque, B_F = B of eq. 6."""
    A, B_torque = plant.linearize()
    A_u, B_u = actuated_linearization(plant, actuator) if actuator is not None else (A, B_torque)
    L = np.asarray(gains, dtype=float).reshape(1, 4)
    return control.ss(A_u + B_u @ L, B_torque, np.eye(4), np.zeros((4, 1)))


def friction_to_arm_velocity(
    plant: FurutaPlant, gains: np.ndarray | list[float], actuator: ActuatorConfig | None = None
) -> control.TransferFunction:
    """G(s) from the friction torque F (entering with u) to φ̇, minimal (section 4, eq. 8–10)."""
    sys = closed_loop_ss(plant, gains, actuator)
    G = control.tf(control.ss(sys.A, sys.B, np.array([[0.0, 0.0, 0.0, 1.0]]), 0.0))
    G = control.minreal(G, tol=1e-7, verbose=False)
    num, den = _clean(np.atleast_1d(np.squeeze(G.num[0][0]))), _clean(np.atleast_1d(np.squeeze(G.den[0][0])))
    return control.tf(num / den[0], den / den[0])


def _clean(c: np.ndarray) -> np.ndarray:
    """Zero the round-off coefficients that minreal leaves behind (relative 1e-9)."""
    c = np.asarray(c, dtype=float).copy()
    c[np.abs(c) < 1e-9 * np.max(np.abs(c))] = 0.0
    return c


def num_den(G: control.TransferFunction) -> tuple[np.ndarray, np.ndarray]:
    return np.atleast_1d(np.squeeze(G.num[0][0])).astype(float), np.atleast_1d(np.squeeze(G.den[0][0])).astype(float)


def real_axis_crossings(G: control.TransferFunction) -> list[tuple[float, float]]:
    """(ω, Re G(jω)) for every ω > 0 where Im G(jω) = 0, exactly: the positive real roots of
    Im[n(jω)·conj(d(jω))], a polynomial in ω."""
    num, den = num_den(G)
    jpow = lambda c: np.array([ck * 1j ** (len(c) - 1 - i) for i, ck in enumerate(c)])  # noqa: E731
    prod = np.polymul(jpow(num), np.conj(jpow(den)))
    im = _clean(prod.imag) if np.any(prod.imag) else prod.imag
    im = np.trim_zeros(im, "f")
    out: list[tuple[float, float]] = []
    if len(im) < 2:
        return out
    for r in np.roots(im):
        if abs(r.imag) > 1e-7 * max(1.0, abs(r)) or r.real <= 1e-9:
            continue
        w = float(r.real)
        d = np.polyval(den, 1j * w)
        if abs(d) < 1e-12 * max(1.0, np.max(np.abs(den))):
            continue  # a pole on the imaginary axis
        out.append((w, float((np.polyval(num, 1j * w) / d).real)))
    return sorted(out)


@dataclass(frozen=True)
class LimitCyclePrediction:
    """One describing-function solution G(jω0) = −πC/(4Fc) (fundamental amplitudes)."""

    omega: float
    g_real: float
    amplitude_phidot: float
    amplitude_phi: float
    amplitude_theta: float
    amplitude_u: float
    stable: bool

    @property
    def period(self) -> float:
        return 2.0 * math.pi / self.omega

    def to_dict(self) -> dict:
        return {
            "frequency_rad_s": self.omega,
            "period_s": self.period,
            "G_real": self.g_real,
            "amplitude_phidot": self.amplitude_phidot,
            "amplitude_phi": self.amplitude_phi,
            "amplitude_theta": self.amplitude_theta,
            "amplitude_u": self.amplitude_u,
            "stable": self.stable,
        }


@dataclass(frozen=True)
class LimitCycleAnalysis:
    gains: np.ndarray
    fc: float
    G: control.TransferFunction
    crossings: list[tuple[float, float]]
    predictions: list[LimitCyclePrediction]
    closed_loop_poles: np.ndarray
    python_control_intersections: list[tuple[float, float]]
    drift_velocity: float | None
    notes: list[str] = field(default_factory=list)

    @property
    def limit_cycle(self) -> bool:
        """The thesis' criterion: G crosses the negative real axis at some ω > 0."""
        return bool(self.predictions)

    @property
    def main(self) -> LimitCyclePrediction | None:
        """The stable prediction if there is one, else the lowest-frequency one."""
        stable = [p for p in self.predictions if p.stable]
        return (stable or self.predictions or [None])[0]

    @property
    def closed_loop_stable(self) -> bool:
        """All poles of A + B L strictly in the left half plane (frictionless linear loop)."""
        return bool(np.all(self.closed_loop_poles.real < -1e-9))

    @property
    def stable_but_arm_drift(self) -> bool:
        """Poles in the open left half plane except exact zeros (φ or φ̇ not fed back)."""
        p = self.closed_loop_poles
        return bool(np.all((p.real < -1e-9) | (np.abs(p) < 1e-7))) and not self.closed_loop_stable

    def to_dict(self) -> dict:
        num, den = num_den(self.G)
        m = self.main
        return {
            "gains": [float(v) for v in self.gains],
            "fc": self.fc,
            "G_num": [float(v) for v in num],
            "G_den": [float(v) for v in den],
            "crossings": [{"omega_rad_s": w, "re": re} for w, re in self.crossings],
            "limit_cycle": self.limit_cycle,
            "frequency_rad_s": m.omega if m else None,
            "period_s": m.period if m else None,
            "amplitude_phidot": m.amplitude_phidot if m else None,
            "amplitude_phi": m.amplitude_phi if m else None,
            "amplitude_theta": m.amplitude_theta if m else None,
            "amplitude_u": m.amplitude_u if m else None,
            "limit_cycle_stable": m.stable if m else None,
            "predictions": [p.to_dict() for p in self.predictions],
            "python_control_intersections": [
                {"amplitude_phidot": a, "frequency_rad_s": w} for a, w in self.python_control_intersections
            ],
            "closed_loop_stable": self.closed_loop_stable,
            "stable_except_arm_drift": self.stable_but_arm_drift,
            "closed_loop_poles": [[float(s.real), float(s.imag)] for s in self.closed_loop_poles],
            "drift_velocity": self.drift_velocity,
            "notes": list(self.notes),
        }


def _loeb_stable(num: np.ndarray, den: np.ndarray, k0: float, omega: float, rel: float = 1e-3) -> bool:
    """Stable limit cycle: a slightly larger amplitude (gain k0(1−rel)) decays, a slightly smaller one
    (k0(1+rel)) grows, and no other root of den + k0·num is in the right half plane."""

    def pair_re(k: float) -> tuple[float, np.ndarray]:
        r = np.roots(np.polyadd(den, k * num))
        i = int(np.argmin(np.abs(r - 1j * omega)))
        return float(r[i].real), r

    re_lo, _ = pair_re(k0 * (1.0 - rel))
    re_hi, _ = pair_re(k0 * (1.0 + rel))
    r0 = np.roots(np.polyadd(den, k0 * num))
    others = r0[(np.abs(r0 - 1j * omega) > 1e-3 * omega) & (np.abs(r0 + 1j * omega) > 1e-3 * omega)]
    return re_lo < 0.0 < re_hi and bool(np.all(others.real < 0.0))


def analyze_limit_cycle(
    plant: FurutaPlant,
    gains: np.ndarray | list[float],
    fc: float = 1.0,
    actuator: ActuatorConfig | None = None,
    with_python_control: bool = True,
) -> LimitCycleAnalysis:
    """Section 4 for u = L·x with Coulomb friction Fc on the arm."""
    L = np.asarray(gains, dtype=float)
    G = friction_to_arm_velocity(plant, L, actuator)
    num, den = num_den(G)
    sys = closed_loop_ss(plant, L, actuator)
    Acl, B = np.asarray(sys.A), np.asarray(sys.B)
    crossings = real_axis_crossings(G)
    preds = []
    for w, re in crossings:
        if re >= 0.0:
            continue
        x = np.linalg.solve(1j * w * np.eye(4) - Acl, B[:, 0]) * (4.0 * fc / math.pi)  # fundamental per unit F
        preds.append(
            LimitCyclePrediction(
                omega=w,
                g_real=re,
                amplitude_phidot=float(abs(x[3])),
                amplitude_phi=float(abs(x[2])),
                amplitude_theta=float(abs(x[0])),
                amplitude_u=float(abs(L @ x)),
                stable=_loeb_stable(num, den, -1.0 / re, w),
            )
        )
    poles = np.linalg.eigvals(Acl)
    notes: list[str] = []
    drift = None
    if abs(den[-1]) > 1e-12 * np.max(np.abs(den)):
        g0 = num[-1] / den[-1] if len(num) else 0.0
        if g0 < -1e-12:
            drift = float(-g0 * fc)
            notes.append(
                f"G(0) = {g0:.4g} < 0: a constant arm velocity φ̇ = {drift:.4g} rad/s balances friction "
                "(a drift, not an oscillation)"
            )
    intersections: list[tuple[float, float]] = []
    if with_python_control and fc > 0:
        intersections = _python_control_intersections(G, fc, crossings)
    lc = LimitCycleAnalysis(L, fc, G, crossings, preds, poles, intersections, drift, notes)
    if preds and not lc.closed_loop_stable and not lc.stable_but_arm_drift:
        notes.append(
            "the frictionless closed loop is unstable: the crossing marks the amplitude above which the oscillation "
            "grows (an unstable limit cycle), not a stable one"
        )
    for p in preds:
        if not p.stable and lc.closed_loop_stable:
            notes.append(f"the solution at {p.omega:.3g} rad/s is an unstable limit cycle (Loeb criterion)")
    return lc


def _python_control_intersections(
    G: control.TransferFunction, fc: float, crossings: list[tuple[float, float]]
) -> list[tuple[float, float]]:
    """The same intersections by python-control's describing_function_response (the cross-check)."""
    omega = np.logspace(-2, 3, 1500)
    scale = max([4 * fc * abs(re) / math.pi for _, re in crossings] + [fc])
    amps = np.logspace(-3, 2, 120) * scale
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        resp = control.describing_function_response(G, CoulombRelay(fc), amps, omega=omega)
    return [(float(a), float(w)) for a, w in resp.intersections]


def sampled_limit_cycle(rig: RigConfig, gains: np.ndarray | list[float], fc: float) -> list[LimitCyclePrediction]:
    """The describing function applied to the loop as it runs: the tick map of
    furuta_rt.controller.loop_analysis (plant, Bessel path, observer, command delay at the loop rate) with
    the friction torque entering the plant directly (held over a tick, unseen by the observer).

    G_s(e^{jωh}) = C_φ̇ (zI − F)⁻¹ Γ_F; solutions where it crosses the negative real axis below the
    Nyquist frequency, with Loeb's criterion on the spectral radius of F − k Γ_F C_φ̇."""
    if rig.control.command_delay_ticks < 1:
        return []  # Γ_F is read off the command pipeline's first slot, which needs a delay
    lm = loop_model(rig, np.asarray(gains, dtype=float))
    n = lm.F.shape[0]
    pipe0 = lm.labels.index("u_pipe0")
    gamma = np.zeros(n)
    gamma[:6] = lm.F_open[:6, pipe0]  # the plant/filter response to one tick of unit arm torque
    c = np.zeros(n)
    c[3] = 1.0
    eye = np.eye(n)

    def resp(w: float) -> np.ndarray:
        return np.linalg.solve(np.exp(1j * w * lm.dt) * eye - lm.F, gamma)

    w = np.logspace(-2, np.log10(0.99 * math.pi / lm.dt), 3000)
    g = np.array([resp(wi)[3] for wi in w])
    out = []
    for i in np.nonzero(np.sign(g.imag[:-1]) != np.sign(g.imag[1:]))[0]:
        w0 = float(brentq(lambda x: resp(x)[3].imag, w[i], w[i + 1]))
        x = resp(w0)
        re = float(x[3].real)
        if re >= 0:
            continue
        x = x * 4.0 * fc / math.pi
        k0 = -1.0 / re

        def radius(k: float, target: complex) -> float:
            ev = np.linalg.eigvals(lm.F - k * np.outer(gamma, c))
            return float(abs(ev[np.argmin(np.abs(ev - target))]))

        z0 = np.exp(1j * w0 * lm.dt)
        stable = radius(k0 * 0.999, z0) < 1.0 < radius(k0 * 1.001, z0)
        out.append(LimitCyclePrediction(
            omega=w0, g_real=re, amplitude_phidot=float(abs(x[3])), amplitude_phi=float(abs(x[2])),
            amplitude_theta=float(abs(x[0])), amplitude_u=float(abs(lm.H[0] @ x)), stable=stable,
        ))
    return out
