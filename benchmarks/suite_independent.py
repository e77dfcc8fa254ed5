"""An independent simulator of the thesis rig for the `diagnose` benchmark (scripts/bench_independent) and tests.

Deliberately NOT built from this project's simulator, sensor path, friction laws or controller — a test oracle that
differs from ours the way another group's simulator would (the one place eq. 4 is derived again, on purpose):

* the plant comes from the Lagrangian of the thesis (section 2.2; lumped parameters computed here from appendix C
  with the thesis' own formulas: α = Jp + M l², β = J + (M + m) r², γ = M r l, ε = l g (M + m/2)), the equations of
  motion by numerical Euler–Lagrange (finite differences of T and V), integrated by fixed-step Runge–Kutta (8 steps
  per tick) with the command held (zero-order hold) from the tick it acts at;
* friction is smooth: Coulomb as Fc·tanh(φ̇ / 1 mrad/s) (no stick state), viscous as b·φ̇;
* θ goes through scipy's analog 2nd-order Bessel (norm='mag', −3 dB at 50 rad/s) integrated with the plant; θ̇ is
  that filter's derivative state; Gaussian noise on both; φ is an encoder of 4096 counts per turn;
* the controller is an LQR (scipy's continuous Riccati solver) on a finite-difference linearisation, φ̇ from a
  filtered difference of the encoder, and an arm reference square wave of ±0.3 rad every 4 s.

On the shared states it agrees with furuta_rt.sim.Simulator to 1e-13 rad over 50 ticks (same plant, same timing:
the command of tick k acts from tick k + latency); what differs is everything around the plant.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy import linalg, signal

from furuta_rt.recording import Recording

G = 9.81
RATE = 500.0
THETA_NOISE, THETA_DOT_NOISE, COUNTS = 2e-4, 2e-3, 4096
COULOMB_VS = 1e-3  # rad/s, the smooth Coulomb law's velocity scale
SUBSTEPS = 8  # RK4 steps per tick


@dataclass(frozen=True)
class Rig:
    """Appendix C of the thesis (what another group would type in), with changes for a case."""

    l: float = 0.413
    r: float = 0.235
    M: float = 0.01
    m: float = 0.02
    Jp: float = 0.0009
    J: float = 0.05

    def lumped(self) -> tuple[float, float, float, float]:
        return (self.Jp + self.M * self.l**2, self.J + (self.M + self.m) * self.r**2, self.M * self.r * self.l,
                self.l * G * (self.M + self.m / 2))


@dataclass(frozen=True)
class Case:
    name: str
    truth: dict[str, dict[str, float]] = field(default_factory=dict)  # the effects a right diagnosis names
    rig: Rig = Rig()
    arm_viscous: float = 0.0
    arm_coulomb: float = 0.0
    pendulum_viscous: float = 0.0
    gain: float = 1.0
    latency_ticks: int = 1
    outside: bool = False  # the mismatch is outside the effect library (a plant parameter)
    seed: int = 0


CASES = [
    Case("null", seed=1),
    Case("arm_viscous", {"arm_viscous": {"Fv": 0.03}}, arm_viscous=0.03, seed=2),
    Case("arm_coulomb", {"arm_coulomb": {"Fc": 0.05}}, arm_coulomb=0.05, seed=3),
    Case("pendulum_viscous", {"pendulum_viscous": {"bp": 2e-4}}, pendulum_viscous=2e-4, seed=4),
    Case("input_gain", {"input_gain": {"gain": 0.7}}, gain=0.7, seed=5),
    Case("latency_0", {"command_latency": {"delay": 0.0}}, latency_ticks=0, seed=6),
    Case("latency_3", {"input_delay": {"delay": 0.004}}, latency_ticks=3, seed=7),
    Case("coulomb+viscous", {"arm_coulomb": {"Fc": 0.03}, "arm_viscous": {"Fv": 0.02}}, arm_viscous=0.02,
         arm_coulomb=0.03, seed=8),
    Case("Jp+20%", rig=Rig(Jp=0.0009 * 1.2), outside=True, seed=9),
    Case("l-10%", rig=Rig(l=0.413 * 0.9), outside=True, seed=10),
]


class Lagrangian:
    """Equations of motion from T and V alone (q = [θ, φ]); θ = 0 upright. Scalar code: it runs every substep."""

    def __init__(self, rig: Rig) -> None:
        self.a, self.b, self.c, self.e = rig.lumped()

    def T(self, th: float, thd: float, phd: float) -> float:
        a, b, c = self.a, self.b, self.c
        return 0.5 * ((b + a * math.sin(th) ** 2) * phd**2 + 2 * c * math.cos(th) * thd * phd + a * thd**2)

    def V(self, th: float) -> float:
        return self.e * math.cos(th)

    def mass(self, th: float) -> tuple[float, float, float]:
        """(M11, M12, M22) = ∂²T/∂q̇² (T is quadratic in q̇: unit-vector differences are exact; T(q, 0) = 0)."""
        t = self.T
        m11, m22 = 2 * t(th, 1.0, 0.0), 2 * t(th, 0.0, 1.0)
        return m11, t(th, 1.0, 1.0) - 0.5 * (m11 + m22), m22

    def accelerations(self, th: float, thd: float, phd: float, q_th: float, q_ph: float) -> tuple[float, float]:
        """M q̈ = Q − (∂(M q̇)/∂θ) θ̇ + ∂(T − V)/∂θ (nothing depends on φ), by central differences in θ."""
        h = 1e-6
        p11, p12, p22 = self.mass(th + h)
        n11, n12, n22 = self.mass(th - h)
        dp_th = ((p11 - n11) * thd + (p12 - n12) * phd) / (2 * h)
        dp_ph = ((p12 - n12) * thd + (p22 - n22) * phd) / (2 * h)
        dL = ((self.T(th + h, thd, phd) - self.V(th + h)) - (self.T(th - h, thd, phd) - self.V(th - h))) / (2 * h)
        f1 = q_th - dp_th * thd + dL
        f2 = q_ph - dp_ph * thd
        m11, m12, m22 = self.mass(th)
        det = m11 * m22 - m12 * m12
        return (m22 * f1 - m12 * f2) / det, (m11 * f2 - m12 * f1) / det


def bessel() -> tuple[float, float, float]:
    """(b0, a1, a0) of scipy's analog 2nd-order Bessel, −3 dB at 50 rad/s: H = b0 / (s² + a1 s + a0)."""
    b, a = signal.bessel(2, 50.0, "low", analog=True, norm="mag")
    return float(b[-1] / a[0]), float(a[1] / a[0]), float(a[2] / a[0])


def lqr(model: Lagrangian) -> np.ndarray:
    """u = −K x on x = [θ, θ̇, φ, φ̇] from a finite-difference linearisation about upright."""
    def f(x: np.ndarray, u: float) -> np.ndarray:
        thdd, phdd = model.accelerations(x[0], x[1], x[3], 0.0, u)
        return np.array([x[1], thdd, x[3], phdd])

    return lqr_about_upright(f, (10.0, 0.1, 3.0, 0.3), 2.0)


def lqr_about_upright(f, q: tuple[float, float, float, float], r: float) -> np.ndarray:
    """K of u = −K x for ẋ = f(x, u) linearised by central differences at x = 0, u = 0 (weights diag(q), r)."""
    h = 1e-6
    A = np.column_stack([(f(h * e, 0.0) - f(-h * e, 0.0)) / (2 * h) for e in np.eye(4)])
    B = ((f(np.zeros(4), h) - f(np.zeros(4), -h)) / (2 * h))[:, None]
    Q, R = np.diag(q), np.array([[r]])
    P = linalg.solve_continuous_are(A, B, Q, R)
    return np.linalg.solve(R, B.T @ P).ravel()


def rk4(f, x: list[float], dt: float, steps: int) -> list[float]:
    """Classical Runge–Kutta, fixed step (the command held over the tick)."""
    for _ in range(steps):
        k1 = f(x)
        k2 = f([xi + 0.5 * dt * ki for xi, ki in zip(x, k1, strict=True)])
        k3 = f([xi + 0.5 * dt * ki for xi, ki in zip(x, k2, strict=True)])
        k4 = f([xi + dt * ki for xi, ki in zip(x, k3, strict=True)])
        x = [xi + dt / 6 * (a + 2 * b + 2 * c + d) for xi, a, b, c, d in zip(x, k1, k2, k3, k4, strict=True)]
    return x


def simulate(case: Case, duration: float, noise: bool = True, noise_scale: float = 1.0, prefilter: float = 0.0,
             coloured: float = 0.0) -> Recording:
    """``duration`` s of the case balanced by the LQR; ``noise``: the sensors' Gaussian noise on θ and θ̇ (the
    encoder's quantisation of φ stays), ``noise_scale`` × its level. Noise a config cannot state (the specificity
    benchmark, suite_null): ``prefilter`` rad of white noise per tick at the Bessel filter's input (held over the
    tick: flat far beyond the filter's band), ``coloured`` × the white levels of first-order low-passed noise (corner
    40 Hz) on θ and θ̇."""
    plant = Lagrangian(case.rig)

    def rhs(x: list[float], tau: float, w: float) -> list[float]:
        th, thd, _ph, phd, y, yd = x
        fr = -case.arm_viscous * phd - case.arm_coulomb * math.tanh(phd / COULOMB_VS)
        thdd, phdd = plant.accelerations(th, thd, phd, -case.pendulum_viscous * thd, tau + fr)
        return [thd, thdd, phd, phdd, yd, b0 * (th + w) - a1 * yd - a0 * y]

    K = lqr(Lagrangian(Rig()))  # the controller is designed on the datasheet rig
    b0, a1, a0 = bessel()
    rng = np.random.default_rng(case.seed)
    h = 1.0 / RATE
    n = round(duration * RATE)
    # state: θ, θ̇, φ, φ̇, y, ẏ (the Bessel filter of θ)
    s = [0.02, 0.0, 0.0, 0.0, 0.02, 0.0]
    pending = [0.0] * case.latency_ticks
    rec = {k: np.empty(n) for k in ("theta", "theta_dot", "phi", "u")}
    true = {k: np.empty(n) for k in ("true_theta", "true_theta_dot", "true_phi", "true_phi_dot", "bessel_y", "bessel_yd")}
    phi_prev, v_hat, tau_v = 0.0, 0.0, 0.01
    c_th = c_thd = 0.0
    pole = math.exp(-2 * math.pi * 40.0 * h)
    for k in range(n):
        t = k * h
        if coloured:
            c_th = pole * c_th + math.sqrt(1 - pole**2) * coloured * THETA_NOISE * rng.standard_normal()
            c_thd = pole * c_thd + math.sqrt(1 - pole**2) * coloured * THETA_DOT_NOISE * rng.standard_normal()
        theta_m = s[4] + noise * noise_scale * THETA_NOISE * rng.standard_normal() + c_th
        theta_dot_m = s[5] + noise * noise_scale * THETA_DOT_NOISE * rng.standard_normal() + c_thd
        phi_m = round(s[2] / (2 * math.pi) * COUNTS) * 2 * math.pi / COUNTS
        if k:
            v_hat += (h / (tau_v + h)) * ((phi_m - phi_prev) / h - v_hat)
        phi_prev = phi_m
        ref = 0.3 if (t % 4.0) < 2.0 else -0.3
        u = float(np.clip(-K @ np.array([theta_m, theta_dot_m, phi_m - ref, v_hat]), -2.0, 2.0))
        rec["theta"][k], rec["theta_dot"][k], rec["phi"][k], rec["u"][k] = theta_m, theta_dot_m, phi_m, u
        for col, v in zip(true.values(), s, strict=True):
            col[k] = v
        pending.append(u)
        acting = case.gain * pending.pop(0)  # the command of tick k acts from tick k + latency

        w = prefilter * rng.standard_normal() if prefilter else 0.0
        s = rk4(lambda x, tau=acting, w=w: rhs(x, tau, w), s, h / SUBSTEPS, SUBSTEPS)
        if abs(s[0]) > 0.6:
            raise RuntimeError(f"{case.name}: the independent controller lost the pendulum at t = {t:.2f} s")
    return Recording(t=np.arange(n) * h, **rec, extra=true, meta={"case": case.name, "simulator": "independent (scipy)"})


def generate(case: Case, duration: float, cache: Path | None = None) -> Recording:
    """The case's recording (from ``cache`` when there: suite.cached)."""
    from benchmarks.suite import cached

    key = hashlib.sha1(repr(("independent", case, duration, INDEPENDENT_CACHE_VERSION)).encode()).hexdigest()[:16]
    return cached(key, cache, lambda: simulate(case, duration))


INDEPENDENT_CACHE_VERSION = 1


def score(case: Case, d: dict) -> dict:
    """Per case: each true effect named with its main parameter within 20 % (a latency within half a tick), or only as
    the declared look-alike of what was named; the effects named that the case does not have (false discoveries,
    counted apart when they stand in for a true effect as its declared look-alike); the verdicts."""
    found = {e["name"]: e["params"] for e in d["effects"]}
    alternatives = {a["alternative"]["name"]: (a["effects"][0], a["alternative"]["params"]) for a in d["ambiguities"]}

    def right(name: str, params: dict[str, float] | None) -> bool:
        key, true = next(iter(case.truth[name].items()))
        got = (params or {}).get(key)
        return got is not None and (abs(got - true) <= 0.2 * abs(true) if true else abs(got) < 0.5 / RATE)

    named = {n: right(n, found.get(n)) for n in case.truth}
    lookalike = {n: not named[n] and n in alternatives and right(n, alternatives[n][1]) for n in case.truth}
    standing_in = {alternatives[n][0] for n, ok in lookalike.items() if ok}
    false = [n for n in found if n not in case.truth and n not in standing_in]
    verdicts = {eq: v.get("verdict") for eq, v in d["equations"].items()}
    ok_verdict = (all(v in ("partly_explained", "unexplained") for v in verdicts.values() if v != "consistent")
                  and any(v in ("partly_explained", "unexplained") for v in verdicts.values())) if case.outside else None
    return {"case": case.name, "found": found, "named": named, "lookalike": lookalike, "false": false,
            "verdicts": verdicts, "outside_verdict_right": ok_verdict, "summary": d.get("summary"),
            "fit": d.get("fit", {}).get("verdict")}
