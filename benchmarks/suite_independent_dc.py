"""Independent recordings of voltage-driven DC-motor rigs for the `diagnose` benchmark (scripts/bench_independent).

The second held-out group beside benchmarks.suite_independent's thesis rig: rigs shaped like the real ones
`diagnose` meets — a QUBE-Servo 2 and the macstepien BLDC rig, driven by voltage, encoders on both joints, a command
latency the config does not state, swing-ups, a gross torque-per-volt error — built, like that group, from none of
this project's simulation code:

* the plant is suite_independent's numerical Euler–Lagrange model (RK4, 8 steps per tick), its lumped parameters
  typed in here from the sources (Quanser's QUBE-Servo 2 manual; the macstepien repository's parameter file) with
  the general-parametrisation formulas α = J2 + m2 l2², β = J_arm + m2 L1², γ = m2 L1 l2, ε = m2 g l2;
* the motor is τ = kt (g·V − km φ̇)/R written here (``amp`` the driver's voltage gain, ``motor`` a factor on both
  kt and km: another motor than the datasheet's), smooth Coulomb friction Fc·tanh(φ̇/vs), viscous friction on both
  joints, a constant arm torque;
* both angles are encoder counts (θ continuous through ±π), no θ̇ column;
* the drivers are written here: an LQR designed on the TRUE rig (a user's working controller is tuned on the
  hardware) on filtered encoder differences, an energy-pumping swing-up (Åström & Furuta 2000, as another group
  would write it) that hands over to it, open-loop voltage steps and chirps with the pendulum hanging.

The diagnosis runs against the shipped config of the shape (``qube_servo2`` or ``macstepien``: one tick of command
latency). The truth is written as effects on that config; the arm's gain, inertia and damping are scored through the
identifiable combinations (suite.arm_combinations), as the realistic group is. Every case is held out: generated once
and not tuned on.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from benchmarks.suite_independent import G, Lagrangian, lqr_about_upright, rk4
from furuta_rt.recording import Recording

RATE = 500.0
SUBSTEPS = 8


@dataclass(frozen=True)
class Shape:
    """A rig as its source gives it (what another group would type in)."""

    name: str  # the shipped config the diagnosis uses
    J_arm: float  # arm (+ rotor, hub) inertia about the motor axis, kg m²
    L1: float  # motor axis to pendulum pivot, m
    m2: float
    l2: float  # pendulum pivot to its centre of mass, m
    J2: float  # pendulum inertia about its centre of mass, kg m²
    kt: float
    km: float
    R: float
    limit: float  # V
    counts: tuple[int, int]  # encoder counts per turn (θ, φ)
    theta_noise: float
    arm_vs: float  # rad/s, the smooth Coulomb law's velocity scale (stiff below it)
    pump_accel: float  # rad/s², the swing-up's arm acceleration
    pump_gain: float = 2.5  # the swing-up's acceleration per relative energy error


# Quanser QUBE-Servo 2 user manual: Rm 8.4 Ω, kt = km = 0.042; arm mr 0.095 kg, Lr 0.085 m, Jr = mr Lr²/12 about the
# motor axis, rotor 4.0e-6, hub mh rh²/2 with mh 0.0106 kg, rh 0.0111 m; pendulum mp 0.024 kg, Lp 0.129 m (rod);
# 2048-count encoders.
QUBE = Shape("qube_servo2", J_arm=0.095 * 0.085**2 / 12 + 4.0e-6 + 0.0106 * 0.0111**2 / 2, L1=0.085, m2=0.024,
             l2=0.129 / 2, J2=0.024 * 0.129**2 / 12, kt=0.042, km=0.042, R=8.4, limit=10.0, counts=(2048, 2048),
             theta_noise=0.0, arm_vs=0.01, pump_accel=150.0)
# macstepien/furuta_pendulum pendulum_parameters.yaml (see ../shared/realdata/macstepien-furuta/README.md): arm
# m1 0.040466 kg at l1 0.05415 m with J1 5.962e-4 about its centre, L1 0.093525 m; pendulum m2 0.009801 kg,
# l2 0.096608 m, J2 1.479e-5; motor Kt 0.103375, R 16 Ω, Kemf 0.001309; an ODrive estimate of θ (fine steps + noise).
MACSTEPIEN = Shape("macstepien", J_arm=5.962e-4 + 0.040466 * 0.05415**2, L1=0.093525, m2=0.009801, l2=0.096608,
                   J2=1.479e-5, kt=0.103375, km=0.001309, R=16.0, limit=12.0, counts=(8192, 8192),
                   theta_noise=5e-5, arm_vs=0.02, pump_accel=150.0)


@dataclass(frozen=True)
class Lumped:
    """α, β, γ, ε for suite_independent.Lagrangian (which only asks for ``lumped()``)."""

    a: float
    b: float
    c: float
    e: float

    def lumped(self) -> tuple[float, float, float, float]:
        return self.a, self.b, self.c, self.e


@dataclass(frozen=True)
class DCCase:
    name: str
    rig: Shape
    drive: str  # balance | swingup | steps | chirp
    truth: dict[str, dict[str, float]] = field(default_factory=dict)  # effects on the shipped config
    amp: float = 1.0  # the driver's voltage gain (1 = as commanded)
    motor: float = 1.0  # kt and km × this (another motor than the datasheet's)
    J_factor: float = 1.0  # the arm's true inertia × this
    l2_factor: float = 1.0  # the pendulum's true centre-of-mass distance × this (outside the library)
    arm_viscous: float = 0.0
    arm_coulomb: float = 0.0
    arm_bias: float = 0.0
    pendulum_viscous: float = 0.0
    latency_ticks: int = 1
    volts: float = 3.0  # open-loop amplitude
    outside: bool = False
    seed: int = 0
    held_out: bool = True

    @property
    def shape(self) -> str:
        """The shipped config the diagnosis runs against (as suite.RealisticCase: score_realistic scores both)."""
        return self.rig.name

    @property
    def injected(self) -> dict[str, dict[str, float]]:
        return self.truth

    @property
    def reference(self) -> str:
        return self.drive


def _latency(ticks: int) -> dict[str, dict[str, float]]:
    return {} if ticks == 1 else {"command_latency": {"delay": ticks / RATE}}


def cases() -> list[DCCase]:
    """Ten held-out recordings; the truth of each is written from its physical change, by hand."""
    q_emf = QUBE.kt * QUBE.km / QUBE.R
    return [
        DCCase("qube/balance null", QUBE, "balance", seed=31),
        DCCase("qube/swingup damping", QUBE, "swingup",
               {"arm_viscous": {"Fv": 5e-4}, "pendulum_viscous": {"bp": 1e-5}},
               arm_viscous=5e-4, pendulum_viscous=1e-5, seed=32),
        DCCase("qube/balance amp×1.5", QUBE, "balance", {"input_gain": {"gain": 1.5}}, amp=1.5, seed=33),
        DCCase("qube/swingup latency 3", QUBE, "swingup", {"arm_viscous": {"Fv": 3e-4}} | _latency(3),
               arm_viscous=3e-4, latency_ticks=3, seed=34),
        DCCase("qube/chirp coulomb", QUBE, "chirp", {"arm_coulomb": {"Fc": 3e-3}}, arm_coulomb=3e-3, seed=35),
        DCCase("qube/balance bias", QUBE, "balance", {"arm_bias": {"tau": 1.5e-3}}, arm_bias=1.5e-3, seed=36),
        # another motor: kt and km both ×2 → torque per volt ×2 and back-EMF damping ×4 (+3× the datasheet's)
        DCCase("qube/steps motor×2", QUBE, "steps",
               {"input_gain": {"gain": 2.0}, "arm_viscous": {"Fv": 3 * q_emf}}, motor=2.0, seed=37),
        DCCase("qube/balance l2+15%", QUBE, "balance", l2_factor=1.15, outside=True, seed=38),
        # the real macstepien rig's steps say ~6.5× the datasheet's torque per volt with b1 ≈ 0.0115 (its README)
        DCCase("macstepien/steps amp×6.5", MACSTEPIEN, "steps",
               {"input_gain": {"gain": 6.5}, "arm_viscous": {"Fv": 0.0115}}, amp=6.5, arm_viscous=0.0115,
               volts=2.0, seed=39),
        DCCase("macstepien/swingup amp×6.5 latency 0", MACSTEPIEN, "swingup",
               {"input_gain": {"gain": 6.5}, "arm_viscous": {"Fv": 0.0115}, "pendulum_viscous": {"bp": 1.8e-5}}
               | _latency(0), amp=6.5, arm_viscous=0.0115, pendulum_viscous=1.8e-5, latency_ticks=0, seed=40),
    ]


def lumped(shape: Shape, J_factor: float = 1.0, l2_factor: float = 1.0) -> Lumped:
    l2 = shape.l2 * l2_factor
    return Lumped(shape.J2 + shape.m2 * l2**2, shape.J_arm * J_factor + shape.m2 * shape.L1**2,
                  shape.m2 * shape.L1 * l2, shape.m2 * G * l2)


class Plant:
    """The true rig of a case: Lagrangian + motor + friction; ``rhs(x, volts)`` on x = [θ, θ̇, φ, φ̇]."""

    def __init__(self, case: DCCase) -> None:
        s = case.rig
        self.case = case
        self.lag = Lagrangian(lumped(s, case.J_factor, case.l2_factor))  # type: ignore[arg-type]
        self.kt, self.km, self.R = s.kt * case.motor, s.km * case.motor, s.R

    def torque(self, volts: float, phd: float) -> float:
        c = self.case
        return (self.kt * (c.amp * volts - self.km * phd) / self.R - c.arm_viscous * phd
                - c.arm_coulomb * math.tanh(phd / c.rig.arm_vs) + c.arm_bias)

    def rhs(self, x: list[float], volts: float) -> list[float]:
        th, thd, _ph, phd = x
        thdd, phdd = self.lag.accelerations(th, thd, phd, -self.case.pendulum_viscous * thd, self.torque(volts, phd))
        return [thd, thdd, phd, phdd]


def lqr_gain(plant: Plant) -> np.ndarray:
    """V = −K x about upright, from a finite-difference linearisation of the true rig (Coulomb and bias left out)."""
    case = plant.case

    def f(x: np.ndarray, v: float) -> np.ndarray:
        tau = plant.kt * (case.amp * v - plant.km * x[3]) / plant.R - case.arm_viscous * x[3]
        thdd, phdd = plant.lag.accelerations(x[0], x[1], x[3], -case.pendulum_viscous * x[1], tau)
        return np.array([x[1], thdd, x[3], phdd])

    return lqr_about_upright(f, (20.0, 0.5, 4.0, 0.2), 1.0)


class SwingUp:
    """Energy pumping (Åström & Furuta 2000): arm acceleration a = a_max·sat(k (E − E_up)/E_up)·sgn(θ̇ cos θ), the arm
    pulled back to the centre, converted to volts through the true rig's arm inertia and motor; the LQR takes over
    within 0.3 rad of upright and hands back beyond 0.7 rad."""

    def __init__(self, plant: Plant, K: np.ndarray) -> None:
        self.plant, self.K, self.balancing = plant, K, False

    def volts(self, th: float, thd: float, ph: float, phd: float) -> float:
        p, case = self.plant, self.plant.case
        a, b, _c, e = p.lag.a, p.lag.b, p.lag.c, p.lag.e
        w = math.atan2(math.sin(th), math.cos(th))
        if self.balancing and abs(w) > 0.7:
            self.balancing = False
        if not self.balancing and abs(w) < 0.3 and abs(thd) < 6.0:
            self.balancing = True
        if self.balancing:
            return float(-self.K @ np.array([w, thd, ph, phd]))
        energy = 0.5 * a * thd**2 + e * math.cos(th)
        push = max(-1.0, min(1.0, case.rig.pump_gain * (energy - 1.1 * e) / e))
        accel = case.rig.pump_accel * push * math.copysign(1.0, thd * math.cos(th) or 1.0)
        accel -= 1.0 * ph + 0.5 * phd  # keep the arm near its start
        tau = b * accel + case.arm_viscous * phd  # the inertia and damping the user tuned on
        return (tau * p.R / p.kt + p.km * phd) / case.amp


def drive_volts(kind: str, n: int, volts: float, seed: int) -> np.ndarray:
    """Open-loop commands with the pendulum hanging: ± steps of random levels (1.5 s on, 1 s off) or a 0.2→3 Hz chirp."""
    t = np.arange(n) / RATE
    if kind == "chirp":
        T = max(t[-1], 1.0)
        return volts * np.sin(2 * np.pi * (0.2 * t + 2.8 * t**2 / (2 * T)))
    rng = np.random.default_rng(seed)
    out = np.zeros(n)
    period = 2.5
    for j in range(int(t[-1] // period) + 1):
        on = (t >= j * period) & (t < j * period + 1.5)
        out[on] = volts * (0.5 + 0.5 * rng.random()) * (1 if j % 2 == 0 else -1)
    return out


def simulate(case: DCCase, duration: float) -> Recording:
    """``duration`` s of the case: the drive's command, latency ``latency_ticks``, encoder readings."""
    s = case.rig
    plant = Plant(case)
    K = lqr_gain(plant)
    rng = np.random.default_rng(case.seed)
    n, h = round(duration * RATE), 1.0 / RATE
    q_th, q_ph = (2 * math.pi / c for c in s.counts)
    hanging = case.drive in ("steps", "chirp", "swingup")
    x = [math.pi - 0.05, 0.0, 0.0, 0.0] if hanging else [0.03, 0.0, 0.0, 0.0]
    swing = SwingUp(plant, K) if case.drive == "swingup" else None
    open_loop = drive_volts(case.drive, n, case.volts, case.seed) if case.drive in ("steps", "chirp") else None
    pending = [0.0] * case.latency_ticks
    rec = {k: np.empty(n) for k in ("theta", "phi", "u")}
    true = {k: np.empty(n) for k in ("true_theta", "true_theta_dot", "true_phi", "true_phi_dot")}
    prev = None
    vth = vph = 0.0
    alpha = h / (0.004 + h)  # the velocity filter's smoothing (4 ms)
    for k in range(n):
        th_m = round(x[0] / q_th) * q_th + s.theta_noise * rng.standard_normal()
        ph_m = round(x[2] / q_ph) * q_ph
        if prev is not None:
            vth += alpha * ((th_m - prev[0]) / h - vth)
            vph += alpha * ((ph_m - prev[1]) / h - vph)
        prev = (th_m, ph_m)
        if open_loop is not None:
            u = float(open_loop[k])
        elif swing is not None:
            u = swing.volts(th_m, vth, ph_m, vph)
        else:
            ref = 0.4 if (k * h) % 6.0 < 3.0 else -0.4
            u = float(-K @ np.array([th_m, vth, ph_m - ref, vph]))
        u = max(-s.limit, min(s.limit, u))
        rec["theta"][k], rec["phi"][k], rec["u"][k] = th_m, ph_m, u
        for col, v in zip(true.values(), x, strict=True):
            col[k] = v
        pending.append(u)
        acting = pending.pop(0)
        x = rk4(lambda y, v=acting: plant.rhs(y, v), x, h / SUBSTEPS, SUBSTEPS)
        if case.drive == "balance" and abs(x[0]) > 0.8:
            raise RuntimeError(f"{case.name}: the independent controller lost the pendulum at t = {k * h:.2f} s")
    return Recording(t=np.arange(n) * h, theta=rec["theta"], phi=rec["phi"], u=rec["u"], theta_dot=None, extra=true,
                     meta={"case": case.name, "simulator": "independent DC rig (numerical Lagrangian, RK4)"})


DC_CACHE_VERSION = 1


def generate(case: DCCase, duration: float, cache: Path | None = None) -> Recording:
    """The case's recording (from ``cache`` when there: suite.cached)."""
    from benchmarks.suite import cached

    key = hashlib.sha1(repr(("independent-dc", case, duration, DC_CACHE_VERSION)).encode()).hexdigest()[:16]
    return cached(key, cache, lambda: simulate(case, duration))
