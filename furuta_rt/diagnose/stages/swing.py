"""A free swing read as such: the shape of its envelope and its period, besides the energy fit of stages/decay.py.

A pendulum swinging about hanging with no command and the arm still loses amplitude only by its pivot friction, and
the two laws of eq. 1 leave different envelopes: viscous friction takes a fixed share of the amplitude per cycle
(an exponential envelope), Coulomb friction a fixed amount (a linear one, ending off-centre). The envelope is read
here without any model of the rig — amplitudes at the turning points against time, fitted by an exponential, a
line and their combination (dA/dt = −λA − s) and compared by leave-one-out error — so its verdict does not lean on
the config. The energy fit (stages/decay.py) sizes the friction with the laws of furuta_rt.model.friction.

The period is the second thing a free swing says. With the arm held, eq. 4 reduces to α θ̈ = −ε sin(θ − π), whose
period at an amplitude depends on ε/α alone (gravity torque m g l over the inertia about the pivot). The config's
period at each cycle's amplitude comes from the energy conservation of the shared plant model (FurutaPlant.energy);
the recording's from the zero crossings. Their ratio squared is (ε/α)_data / (ε/α)_config: the one combination of
the pendulum's parameters a free decay pins — which of mass, centre of mass or inertia is off it cannot tell.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from furuta_rt.config import RigConfig
from furuta_rt.diagnose.regression.states import Prepared
from furuta_rt.model.plant import FurutaPlant

COMMAND_OFF = 0.01  # a command below this share of the actuator's limit everywhere is no command
ARM_STILL_RAD = 0.05  # the arm's whole travel below this is an arm held still ...
ARM_STILL_RATE = 0.05  # ... and so is an arm whose rms rate is below this share of the pendulum's
SWING_MIN_RAD = 0.1  # the pendulum swings through at least this range
PERIOD_Z = 4.0  # the period's ratio to the config's reported as a mismatch beyond this many standard errors
PERIOD_MIN = 0.01  # ... and beyond this relative change of ε/α
TOO_FEW = ("the recording is a free swing (no command, the arm still) of fewer than 5 full cycles above the noise: its "
           "loss per cycle is not fitted; record the swing until it has nearly stopped")
SHAPE_MARGIN = 0.1  # the combined envelope is named only when it cuts the better single shape's error by this share


def is_free_swing(prep: Prepared, rig: RigConfig | None = None) -> bool:
    """No command (|u| under COMMAND_OFF of the actuator's limit, zero without a rig), the arm practically still (its
    travel under ARM_STILL_RAD, or its rms rate under ARM_STILL_RATE of the pendulum's), the pendulum swinging
    through SWING_MIN_RAD at least."""
    v = prep.valid
    if not v.any():
        return False
    limit = COMMAND_OFF * rig.actuator.limit if rig is not None else 0.0
    if float(np.max(np.abs(prep.u[v]))) > limit:
        return False
    if float(np.ptp(prep.theta_f[v])) < SWING_MIN_RAD:
        return False
    if float(np.ptp(prep.phi[v])) < ARM_STILL_RAD:
        return True
    phi_rate = np.diff(prep.phi[v]) / prep.dt
    theta_rate = np.diff(prep.theta_f[v]) / prep.dt
    return float(np.std(phi_rate)) < ARM_STILL_RATE * float(np.std(theta_rate))


# ------------------------------------------------------------------------------ the envelope
@dataclass(frozen=True)
class Envelope:
    shape: str  # "exponential" | "linear" | "both"
    rate: float  # λ of the exponential part, 1/s (0 for a linear envelope)
    slope: float  # s of the linear part, rad/s (0 for an exponential envelope)
    loo: dict[str, float]  # leave-one-out rms amplitude error (rad) of each shape
    start: float  # fitted amplitude at the first turning point, rad
    end: float  # ... at the last
    points: int

    def as_json(self) -> dict:
        return {"shape": self.shape, "rate_per_s": self.rate, "slope_rad_per_s": self.slope,
                "loo_rms_rad": self.loo, "start_rad": self.start, "end_rad": self.end, "turning_points": self.points}

    def text(self, period: float | None) -> str:
        per = (f"{100 * (1 - np.exp(-self.rate * period)):.1f} % of the amplitude per cycle" if period else
               f"λ = {self.rate:.3g}/s")
        lin = f"{self.slope * period:.3g} rad per cycle" if period else f"{self.slope:.3g} rad/s"
        what = {"exponential": f"exponential (a fixed share, {per}: viscous)",
                "linear": f"linear (a fixed amount, {lin}: Coulomb)",
                "both": f"exponential and linear together ({per} and {lin}: viscous and Coulomb)"}[self.shape]
        errs = ", ".join(f"{k} {v:.2g} rad" for k, v in self.loo.items())
        return (f"the swing's envelope falls from {self.start:.3g} to {self.end:.3g} rad over {self.points} turning "
                f"points, {what}; leave-one-out amplitude error: {errs}")


def _fit_shape(tau: np.ndarray, a: np.ndarray, shape: str) -> tuple[np.ndarray, float, float]:
    """(fitted amplitudes, λ, s) of one envelope shape by least squares; the combined one A e^(−λτ) − B (B = s/λ ≥ 0)
    profiled over λ."""
    one = np.ones_like(tau)
    if shape == "linear":
        c, *_ = np.linalg.lstsq(np.column_stack([one, -tau]), a, rcond=None)
        return c[0] - c[1] * tau, 0.0, max(float(c[1]), 0.0)
    if shape == "exponential":
        lam = _exp_rate(tau, a)
        e = np.exp(-lam * tau)
        amp = float(e @ a / (e @ e))
        return amp * e, lam, 0.0
    span = max(float(tau[-1] - tau[0]), 1e-9)
    best = (np.inf, None, 0.0, 0.0)
    for lam in np.geomspace(0.01 / span, 30.0 / span, 80):
        X = np.column_stack([np.exp(-lam * tau), -one])
        c, *_ = np.linalg.lstsq(X, a, rcond=None)
        if c[1] < 0:  # a negative linear part is growth, no friction: the exponential alone then
            continue
        fitted = X @ c
        err = float(np.sum((a - fitted) ** 2))
        if err < best[0]:
            best = (err, fitted, float(lam), float(lam * c[1]))
    if best[1] is None:
        return _fit_shape(tau, a, "exponential")
    return best[1], best[2], best[3]


def _exp_rate(tau: np.ndarray, a: np.ndarray) -> float:
    """λ of a·e^(−λτ) by least squares on the amplitudes (a 1-D profile: the amplitude factor is linear)."""
    span = max(float(tau[-1] - tau[0]), 1e-9)
    lams = np.geomspace(0.01 / span, 30.0 / span, 120)
    errs = []
    for lam in lams:
        e = np.exp(-lam * tau)
        errs.append(float(np.sum((a - (e @ a / (e @ e)) * e) ** 2)))
    return float(lams[int(np.argmin(errs))])


def envelope(t: np.ndarray, amplitude: np.ndarray) -> Envelope | None:
    """The envelope through the turning-point amplitudes ``amplitude`` (rad from the swing's centre) at times ``t``;
    None with fewer than 6 points."""
    keep = amplitude > 0
    t, a = t[keep], amplitude[keep]
    if len(a) < 6:
        return None
    tau = t - t[0]
    loo = {}
    for shape in ("exponential", "linear", "both"):
        errs = []
        for i in range(len(a)):
            m = np.arange(len(a)) != i
            fitted, lam, s = _fit_shape(tau[m], a[m], shape)
            pred = _predict(tau[m], a[m], fitted, lam, s, shape, tau[i])
            errs.append(pred - a[i])
        loo[shape] = float(np.sqrt(np.mean(np.square(errs))))
    single = min(("exponential", "linear"), key=lambda k: loo[k])
    shape = "both" if loo["both"] < (1 - SHAPE_MARGIN) * loo[single] else single
    fitted, lam, s = _fit_shape(tau, a, shape)
    return Envelope(shape, lam, s, loo, float(fitted[0]), float(fitted[-1]), len(a))


def _predict(tau: np.ndarray, a: np.ndarray, fitted: np.ndarray, lam: float, s: float, shape: str, at: float) -> float:
    """A fitted shape's amplitude at ``at`` (its parameters recovered from the fit on ``tau``)."""
    if shape == "linear":
        c = np.polyfit(tau, fitted, 1)
        return float(np.polyval(c, at))
    if shape == "exponential":
        amp = float(fitted[0] / np.exp(-lam * tau[0]))
        return amp * float(np.exp(-lam * at))
    b = s / lam if lam > 0 else 0.0
    amp = float((fitted[0] + b) / np.exp(-lam * tau[0]))
    return amp * float(np.exp(-lam * at)) - b


# ------------------------------------------------------------------------------ the period
def config_period(plant: FurutaPlant, amplitude: float, nodes: int = 48) -> float:
    """The period of the config's pendulum swinging about hanging with amplitude ``amplitude`` (rad) and the arm
    held (φ̇ = 0), from its energy conservation: T = 4∫₀^A dx / θ̇(x), θ̇² = (E(π + A, 0) − E(π + x, 0)) / c(x)
    with c the kinetic coefficient of FurutaPlant.energy; x = A sin s takes out the turning point's singularity."""
    s, w = np.polynomial.legendre.leggauss(nodes)
    s = 0.25 * np.pi * (s + 1.0)  # [0, π/2]
    w = 0.25 * np.pi * w
    x = amplitude * np.sin(s)
    top = plant.energy(np.pi + amplitude, 0.0, 0.0)
    pot = plant.energy(np.pi + x, 0.0, 0.0)
    c = plant.energy(np.pi + x, 1.0, 0.0) - pot
    # (top − pot) = ε (cos x − cos A) ∝ (A² − x²) ∝ cos² s near the turning point: the ratio below stays finite
    rate = np.sqrt(np.maximum(top - pot, 1e-300) / c)
    return float(4.0 * np.sum(w * amplitude * np.cos(s) / rate))


@dataclass(frozen=True)
class Period:
    measured: float  # s, median over the cycles
    config: float  # s, the config's at the same amplitudes
    ratio: float  # (ε/α) of the data over the config's
    se: float
    cycles: int
    amplitude: float  # median amplitude of the cycles used, rad

    @property
    def mismatch(self) -> bool:
        return abs(self.ratio - 1) >= max(PERIOD_Z * self.se, PERIOD_MIN)

    def as_json(self) -> dict:
        return {"measured_s": self.measured, "config_s": self.config, "epsilon_over_alpha_ratio": self.ratio,
                "se": self.se, "cycles": self.cycles, "amplitude_rad": self.amplitude, "mismatch": self.mismatch}

    def text(self) -> str:
        head = (f"the swing's period is {self.measured:.4g} s at {self.amplitude:.2g} rad ({self.cycles} cycles); the "
                f"config's pendulum, arm held, swings in {self.config:.4g} s there")
        if not self.mismatch:
            return head + f": ε/α agrees ({self.ratio:.3f} × config ± {self.se:.2g})"
        return (head + f": ε/α (gravity torque m g l over the inertia about the pivot) is {self.ratio:.3f} × config "
                f"(± {self.se:.2g}). A free decay pins this ratio only — a mass, a centre of mass or an inertia off by "
                "the same ratio look alike; a static torque test (the pendulum held horizontal on a scale gives m g l) "
                "separates them")


def period(prep: Prepared, rig: RigConfig, centre: float, start: float, stop: float) -> Period | None:
    """The swing's period from the zero crossings of θ − π − ``centre`` between ``start`` and ``stop`` (s, the first
    and last turning points of the swing), cycle by cycle, against the config's at each cycle's amplitude; None with
    fewer than 3 cycles."""
    v = np.flatnonzero(prep.valid)
    t = prep.t[v]
    x = np.angle(np.exp(1j * (prep.theta_f[v] - np.pi))) - centre
    after = (t >= start) & (t <= stop)
    t, x = t[after], x[after]
    neg = x < 0  # (a quantised angle sits at exactly 0: sign() would count such a crossing twice)
    idx = np.flatnonzero((neg[:-1] != neg[1:]) & (np.abs(x[:-1] - x[1:]) < 1.0))
    if len(idx) < 7:
        return None
    tc = t[idx] + (t[idx + 1] - t[idx]) * x[idx] / (x[idx] - x[idx + 1])  # linear interpolation of the crossing
    plant = FurutaPlant(rig.lumped())
    meas, cfg, amps = [], [], []
    for k in range(len(tc) - 2):
        seg = slice(idx[k], idx[k + 2] + 1)
        amp = 0.5 * (float(np.max(x[seg])) - float(np.min(x[seg])))
        if not 0 < amp < 2.5:
            continue
        meas.append(tc[k + 2] - tc[k])
        cfg.append(config_period(plant, amp))
        amps.append(amp)
    # every other period shares a half-cycle with its neighbour: the independent ones are every second
    r = (np.asarray(cfg) / np.asarray(meas)) ** 2
    if len(r) < 3:
        return None
    se = float(np.std(r[::2], ddof=1) / np.sqrt(len(r[::2]))) if len(r[::2]) > 1 else float("inf")
    return Period(float(np.median(meas)), float(np.median(cfg)), float(np.median(r)), se, len(r),
                  float(np.median(amps)))


# ------------------------------------------------------------------------------ the stage
@dataclass(frozen=True)
class Swing:
    envelope: Envelope | None
    period: Period | None
    arm_held: bool
    lossless: bool = False  # the energy fit finds no measurable loss (stages/decay.py)

    def as_json(self) -> dict:
        return {"envelope": self.envelope.as_json() if self.envelope else None,
                "period": self.period.as_json() if self.period else None, "arm_held": self.arm_held}

    def notes(self) -> list[str]:
        out = []
        if self.envelope is not None and self.lossless:
            out.append(f"the swing keeps its amplitude ({self.envelope.start:.3g} → {self.envelope.end:.3g} rad over "
                       f"{self.envelope.points} turning points): no measurable loss, no pivot friction to name")
        elif self.envelope is not None:
            out.append(self.envelope.text(self.period.measured if self.period else None))
        if self.period is not None:
            out.append(self.period.text())
        elif not self.arm_held:
            out.append("the arm moves with the swing: the period is the coupled one, not compared with the config's")
        return out


def read(prep: Prepared, rig: RigConfig, peaks_t: np.ndarray, centre: float, lossless: bool = False) -> Swing:
    """The envelope through the turning points at ``peaks_t`` (amplitudes about ``centre``, where the swing settles,
    rad from hanging) and, with the arm held, the period against the config's."""
    peaks_t = np.asarray(peaks_t)
    x = np.angle(np.exp(1j * (prep.theta_f - np.pi))) - centre
    at = np.clip(np.searchsorted(prep.t, peaks_t), 0, prep.n - 1)
    env = envelope(peaks_t, np.abs(x[at])) if len(peaks_t) else None
    held = float(np.ptp(prep.phi[prep.valid])) < ARM_STILL_RAD
    per = period(prep, rig, centre, float(peaks_t[0]), float(peaks_t[-1])) if held and len(peaks_t) else None
    return Swing(env, per, held, lossless)
