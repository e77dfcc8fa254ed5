"""Pendulum free decay: viscous or Coulomb pivot friction, from the energy lost per swing.

When the pendulum swings freely (no command, the arm nearly still), the energy E = T + V of eq. 4
(FurutaPlant.energy) only falls by the pivot friction. Over one full cycle, between two turning points
on the same side (θ̇ = 0, where a sensor offset affects E alike at both ends),

    E(start) − E(end) = bp·∫θ̇² dt + Fc·∫|θ̇| dt        (viscous bp, Coulomb Fc; eq. 1 with a small ε),

so the loss per cycle is regressed on the two integrals, in relative terms (each cycle weighs alike).
This is the envelope test in energy form: a viscous loss shrinks with the square of the amplitude (an
exponential envelope), a Coulomb loss with the amplitude itself (a linear envelope, and the pendulum
stops off-centre). The models — viscous only,
Coulomb only, both — are compared by their leave-one-cycle-out prediction error.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from furuta_rt.config import RigConfig
from furuta_rt.diagnose.regression.states import Prepared
from furuta_rt.model.friction import Coulomb, Viscous
from furuta_rt.model.plant import FurutaPlant
from furuta_rt.model.rig import PENDULUM_COULOMB_EPSILON

MIN_CYCLES = 5
LOSS_Z = 3.0  # a loss: the mean energy lost per cycle this many standard errors above zero ...
SIGN_Z = 2.0  # ... or more cycles losing energy than gaining it, by this many standard deviations of a fair coin
AMPLITUDE_RESOLUTIONS = 10.0  # a cycle counts when its amplitude is this many θ resolutions (LSB or noise)


@dataclass(frozen=True)
class DecayFit:
    name: str  # "viscous" | "coulomb" | "both" | "none" (no measurable loss)
    bp: float
    Fc: float
    loo_rms: float  # leave-one-cycle-out rms relative error of the energy lost per cycle
    se_bp: float = 0.0  # jackknife standard errors over the cycles
    se_Fc: float = 0.0


@dataclass(frozen=True)
class DecayResult:
    cycles: int
    amplitude: np.ndarray  # amplitude (rad from the swing centre) at the start of each cycle
    t: np.ndarray  # start time of each cycle
    loss: np.ndarray  # energy lost over each cycle (J)
    fits: dict[str, DecayFit]
    best: str
    rest_offset: float  # where the swing settles, rad from hanging (θ = π)
    peaks_t: np.ndarray
    peaks: np.ndarray  # |θ − π| at each turning point
    regressors: np.ndarray  # (cycles, 2): ∫θ̇² dt and ∫|θ̇| dt (eq. 1) per cycle

    def predicted_loss(self, name: str) -> np.ndarray:
        f = self.fits[name]
        return self.regressors @ np.array([f.bp, f.Fc])

    def as_json(self) -> dict:
        return {
            "cycles": self.cycles, "best": self.best, "rest_offset": self.rest_offset,
            "fits": {
                k: {"bp": f.bp, "Fc": f.Fc, "se_bp": f.se_bp, "se_Fc": f.se_Fc, "loo_relative_error": f.loo_rms}
                for k, f in self.fits.items()
            },
        }


def _loo(X: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """(coefficients, leave-one-out rms error, jackknife standard errors)."""
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    H = X @ np.linalg.pinv(X.T @ X) @ X.T
    r = (y - X @ coef) / np.maximum(1 - np.diag(H), 1e-9)
    n = len(y)
    folds = np.array([np.linalg.lstsq(np.delete(X, i, 0), np.delete(y, i), rcond=None)[0] for i in range(n)])
    se = np.sqrt((n - 1) / n * np.sum((folds - folds.mean(0)) ** 2, axis=0))
    return coef, float(np.sqrt(np.mean(r**2))), se


def free_decay(prep: Prepared, rig: RigConfig, sigma: float = 0.005, stop_time: float | None = None) -> DecayResult | None:
    """The energy-per-cycle analysis of a free decay (None when there are too few cycles); ``stop_time``:
    use only the cycles that end before it."""
    s = prep.states(sigma)
    plant = FurutaPlant(rig.lumped())
    v = np.flatnonzero(prep.valid)
    th, thd = s.theta[v], s.theta_dot[v]
    t = prep.t[v]
    energy = np.array([plant.energy(a, b, c) for a, b, c in zip(th, thd, s.phi_dot[v], strict=True)])
    # turning points: θ̇ changes sign, away from the final rest (|θ̇| swings above noise)
    level = 0.02 * float(np.max(np.abs(thd)))
    sign = np.sign(thd)
    turns = [i for i in np.flatnonzero(np.diff(sign) != 0) if np.max(np.abs(thd[max(0, i - 50) : i + 50])) > level]
    # drop the fall from upright: start at the first turning point within a half turn of hanging
    x = np.angle(np.exp(1j * (th - np.pi)))  # θ − π wrapped to (−π, π]
    turns = [i for i in turns if abs(x[i]) < 2.5 and (stop_time is None or t[i] < stop_time)]
    if len(turns) < 2 * MIN_CYCLES + 1:
        return None
    visc = Viscous(1.0)
    coul = Coulomb(1.0, PENDULUM_COULOMB_EPSILON)
    dt = prep.dt
    rows, amp, t0 = [], [], []
    for a, b in zip(turns[:-2:2], turns[2::2], strict=False):
        seg = slice(a, b + 1)
        rows.append((
            energy[a] - energy[b],
            -float(np.sum(visc.torque(thd[seg]) * thd[seg]) * dt),  # ∫ bp θ̇² / bp
            -float(np.sum(np.vectorize(coul.torque)(thd[seg]) * thd[seg]) * dt),  # ∫ Fc |θ̇| / Fc
        ))
        amp.append(float(np.max(np.abs(x[seg]))))
        t0.append(float(t[a]))
    R = np.asarray(rows)
    # cycles that moved and lost energy (not a stuck tail), with an amplitude well above the θ sensor's resolution:
    # below it the energy lost is the reading's noise, which the relative weighting below would let dominate
    resolution = max(rig.sensors.theta_rad_per_count, rig.sensors.theta_noise)
    moved = (R[:, 2] > 0) & (np.asarray(amp) >= AMPLITUDE_RESOLUTIONS * resolution)
    # a loss at all: the reading's noise gives losses and gains alike, a friction losses. Lossless when neither do the
    # losses outnumber the gains (sign test) nor does their mean stand out of its scatter (a decaying series of losses
    # has a large scatter, so the sign test carries it)
    losses = R[moved, 0]
    n = len(losses)
    sign_z = (int(np.sum(losses > 0)) - n / 2) / (np.sqrt(n) / 2) if n else 0.0
    spread = float(np.std(losses, ddof=1)) / np.sqrt(n) if n > 1 else 0.0
    lossless = n >= MIN_CYCLES and sign_z < SIGN_Z and float(np.mean(losses)) < LOSS_Z * spread
    keep = (R[:, 0] > 0) & moved
    R = R[keep]
    amp = list(np.asarray(amp)[keep])
    t0 = list(np.asarray(t0)[keep])
    if len(R) < MIN_CYCLES:
        return None
    # relative errors: every cycle counts alike, so the small swings (where Coulomb friction shows) weigh as
    # much as the large ones (where viscous friction dominates)
    w = 1.0 / R[:, 0]
    y, Xv, Xc = R[:, 0] * w, R[:, 1:2] * w[:, None], R[:, 2:3] * w[:, None]
    fits = {}
    for name, X in (("viscous", Xv), ("coulomb", Xc), ("both", np.hstack([Xv, Xc]))):
        coef, loo, se = _loo(X, y)
        bp = float(coef[0]) if name != "coulomb" else 0.0
        fc = float(coef[-1]) if name != "viscous" else 0.0
        se_bp = float(se[0]) if name != "coulomb" else 0.0
        se_fc = float(se[-1]) if name != "viscous" else 0.0
        fits[name] = DecayFit(name, bp, fc, loo, se_bp, se_fc)
    admissible = [n for n, f in fits.items() if f.bp >= 0 and f.Fc >= 0]
    best = min(admissible or list(fits), key=lambda n: fits[n].loo_rms)
    if lossless:  # no loss to name: the energy per cycle is constant within its noise
        fits["none"] = DecayFit("none", 0.0, 0.0, float("nan"))
        best = "none"
    tail = x[-max(10, len(x) // 20) :]
    return DecayResult(
        cycles=len(R), amplitude=np.asarray(amp), t=np.asarray(t0), loss=R[:, 0], fits=fits, best=best,
        rest_offset=float(np.median(tail)), peaks_t=t[turns], peaks=np.abs(x[turns]), regressors=R[:, 1:3],
    )
