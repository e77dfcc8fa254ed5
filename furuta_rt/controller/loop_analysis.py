"""The sampled closed loop as it runs on the rig, linearised: plant (eq. 6) + Bessel path +
φ̇ observer + the controller's command delay, at the loop rate.

``closed_loop`` builds the one-tick map of the whole loop as a matrix (by feeding unit vectors through
the same tick equations the controller uses), so its eigenvalues are the closed-loop poles with the
filter and observer included, and ``loop_gain`` gives the loop broken at the actuator for margins.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from furuta_rt.config import RigConfig
from furuta_rt.controller.controller import design_gains, observer_design
from furuta_rt.controller.design import actuated_linearization
from furuta_rt.model.plant import FurutaPlant
from furuta_rt.model.sensors import BesselPath


@dataclass(frozen=True)
class LoopModel:
    """Closed loop x⁺ = F x. Broken at the actuator: x⁺ = F_open x + G v (v: the command sent),
    u = H x + J v (u: what the controller computes)."""

    F: np.ndarray
    F_open: np.ndarray
    G: np.ndarray
    H: np.ndarray
    J: np.ndarray
    dt: float
    labels: tuple[str, ...]


def _plant_and_filter(A4: np.ndarray, B4: np.ndarray, bessel: BesselPath | None) -> tuple[np.ndarray, np.ndarray]:
    """Continuous (A, B) of [θ, θ̇, φ, φ̇, θ_f, θ̇_f] driven by the actuator command."""
    A = np.zeros((6, 6))
    B = np.zeros((6, 1))
    A[:4, :4] = A4
    B[:4] = B4
    if bessel is None:
        # No filter: θ_f follows θ exactly; model as a very fast first-order follower.
        A[4, 4] = A[5, 5] = -1e4
        A[4, 0] = A[5, 1] = 1e4
    else:
        Af, Bf, _ = bessel.state_space()
        A[4:6, 4:6] = Af
        A[4:6, 0:1] = Bf
    return A, B


def loop_model(rig: RigConfig, gains: np.ndarray | None = None) -> LoopModel:
    """Linear tick map of the loop for the rig's configured gains, filter, observer and delay."""
    plant = FurutaPlant(rig.lumped())
    L = design_gains(rig) if gains is None else np.asarray(gains, dtype=float)
    h = 1.0 / rig.control.rate_hz
    s = rig.sensors
    bessel = BesselPath(s.bessel_cutoff) if s.bessel_cutoff else None
    Ac, Bc = _plant_and_filter(*actuated_linearization(plant, rig.actuator), bessel)
    import scipy.linalg  # here, not above: the CLI (and so the real-time process) imports this module

    # Zero-order hold discretisation.
    M = scipy.linalg.expm(np.block([[Ac, Bc], [np.zeros((1, 7))]]) * h)
    Phi, Gam = M[:6, :6], M[:6, 6:7]
    obs = observer_design(rig)
    D = rig.control.command_delay_ticks
    n = 6 + 2 + max(D, 1)
    # state: [plant+filter (6), observer prior φ̂, φ̂̇ (2), torque pipeline (D; slot 0 acts now)]

    def tick(x: np.ndarray, v: float, closed: bool) -> tuple[np.ndarray, float]:
        """One tick. closed: the command sent is the controller's u; open: it is v (loop broken)."""
        p = x[:6]
        xo = x[6:8]
        pipe = x[8:]
        theta_f, theta_dot_f, phi = p[4], p[5], p[2]
        innov = phi - xo[0]
        post = xo + obs.K * innov
        u = L[0] * theta_f + L[1] * theta_dot_f + L[2] * phi + L[3] * post[1]
        sent = u if closed else v
        applied_now = pipe[0] if D else sent
        p_next = Phi @ p + Gam[:, 0] * applied_now
        pipe_next = np.concatenate([pipe[1:], [sent]]) if D else pipe
        # the observer's model torque over the next period is the one reaching the plant then
        obs_torque = applied_now
        xo_next = obs.Ad @ post + obs.Bd @ np.array([theta_f, obs_torque])
        return np.concatenate([p_next, xo_next, pipe_next]), u

    F = np.zeros((n, n))
    F_open = np.zeros((n, n))
    H = np.zeros((1, n))
    for j in range(n):
        e = np.zeros(n)
        e[j] = 1.0
        F[:, j], H[0, j] = tick(e, 0.0, closed=True)
        F_open[:, j], _ = tick(e, 0.0, closed=False)
    G_col, J_val = tick(np.zeros(n), 1.0, closed=False)
    labels = ("theta", "theta_dot", "phi", "phi_dot", "theta_f", "theta_dot_f", "phi_hat", "phi_dot_hat") + tuple(
        f"u_pipe{i}" for i in range(n - 8)
    )
    return LoopModel(
        F=F, F_open=F_open, G=G_col.reshape(-1, 1), H=H, J=np.array([[J_val]]), dt=h, labels=labels
    )


@dataclass(frozen=True)
class LoopReport:
    gains: np.ndarray
    poles_z: np.ndarray
    poles_s: np.ndarray  # continuous equivalents log(z)/h of the non-zero discrete poles
    stable: bool
    gain_margin_down: float  # the loop stays stable for loop gains down to this factor
    gain_margin_up: float  # ... and up to this one
    phase_margin_deg: float
    ideal_poles: np.ndarray  # eig(A + B L): continuous, no filter, no observer, no delay
    notes: list[str]


def _stable(poles_z: np.ndarray) -> bool:
    """Every closed-loop pole strictly inside the unit circle."""
    return bool(np.all(np.abs(poles_z) < 1.0 - 1e-9))


def analyze(rig: RigConfig, gains: np.ndarray | None = None) -> LoopReport:
    lm = loop_model(rig, gains)
    L = design_gains(rig) if gains is None else np.asarray(gains, dtype=float)
    z = np.linalg.eigvals(lm.F)
    stable = _stable(z)
    nz = z[np.abs(z) > 1e-9]
    s = np.log(nz.astype(complex)) / lm.dt
    order = np.argsort(-s.real)
    s = s[order]
    gm_down, gm_up, pm = margins(lm)
    A, B = actuated_linearization(FurutaPlant(rig.lumped()), rig.actuator)
    ideal = np.linalg.eigvals(A + B @ L.reshape(1, 4))
    notes: list[str] = []
    if not stable:
        worst = float(np.max(np.abs(z)))
        cutoff = rig.sensors.bessel_cutoff
        if cutoff is not None and bool(np.all(ideal.real < 0)):
            notes.append(
                f"UNSTABLE with the configured θ filter (Bessel cutoff {cutoff:g} rad/s, largest |z| = {worst:.3f}): "
                "the filter's phase lag destabilises a loop that is stable without it; raise "
                "sensors.bessel_cutoff (see `furuta-rt design` with a higher cutoff) or slow the design down"
            )
        else:
            notes.append(f"UNSTABLE: largest closed-loop |z| = {worst:.3f}")
    return LoopReport(
        gains=L, poles_z=z, poles_s=s, stable=stable, gain_margin_down=gm_down, gain_margin_up=gm_up, phase_margin_deg=pm,
        ideal_poles=ideal, notes=notes,
    )


def loop_frequency_response(lm: LoopModel, omega: np.ndarray) -> np.ndarray:
    """L(e^{jωh}) = −(H (zI − F_open)⁻¹ G + J), the loop broken at the actuator."""
    z = np.exp(1j * np.asarray(omega, dtype=float) * lm.dt)
    resolvent_G = np.linalg.solve(z[:, None, None] * np.eye(lm.F_open.shape[0]) - lm.F_open, lm.G)  # one per ω
    return -((lm.H @ resolvent_G)[:, 0, 0] + lm.J[0, 0])


def margins(lm: LoopModel, n: int = 6000) -> tuple[float, float, float]:
    """(gain margin down, gain margin up, phase margin in degrees) from the loop's frequency response.

    The pendulum is open-loop unstable, so the stable gains form an interval [down, up] around 1;
    each crossing of the negative real axis at −a bounds it at 1/a.
    """
    omega = np.logspace(-2, np.log10(np.pi / lm.dt * 0.999), n)
    Lw = loop_frequency_response(lm, omega)
    down, up = 0.0, float("inf")
    im = Lw.imag
    for i in np.nonzero(np.sign(im[:-1]) != np.sign(im[1:]))[0]:
        f = im[i] / (im[i] - im[i + 1])
        re = Lw[i].real + f * (Lw[i + 1].real - Lw[i].real)
        if re < 0:
            k = -1.0 / re
            if k < 1.0:
                down = max(down, k)
            else:
                up = min(up, k)
    mag = np.abs(Lw) - 1.0
    pms = []
    for i in np.nonzero(np.sign(mag[:-1]) != np.sign(mag[1:]))[0]:
        ph = np.degrees(np.angle(Lw[i]))
        pms.append(abs(((ph + 180.0) + 180.0) % 360.0 - 180.0))
    return down, up, float(min(pms)) if pms else float("inf")


def minimum_stable_cutoff(rig: RigConfig, lo: float = 1.0, hi: float = 1000.0) -> float | None:
    """Smallest Bessel cutoff (rad/s) for which the configured loop is stable (bisection on the poles of
    ``loop_model``; the gains do not depend on the filter, so they are designed once)."""
    gains = design_gains(rig)

    def ok(c: float) -> bool:
        r = rig.model_copy(deep=True)
        r.sensors.bessel_cutoff = c
        return _stable(np.linalg.eigvals(loop_model(r, gains).F))

    if not ok(hi):
        return None
    if ok(lo):
        return lo
    for _ in range(40):
        mid = (lo * hi) ** 0.5
        lo, hi = (lo, mid) if ok(mid) else (mid, hi)
        if hi / lo < 1.001:
            break
    return hi
