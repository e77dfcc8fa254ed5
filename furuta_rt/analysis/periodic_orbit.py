"""The friction limit cycle as a periodic orbit of the nonlinear closed loop (beyond the describing
function of section 4, which assumes a sinusoidal φ̇ and misses the stick phases).

Shooting on a Poincaré section: the section is the upward zero crossing of θ (transversal and smooth:
the pendulum never sticks, while φ̇ = 0 holds over whole stick phases). The return map P takes the
loop state on the section to the state at its next crossing (m crossings if the orbit crosses more
than once per period); the orbit is the fixed point P(x*) = x*, found by Newton's method with a
finite-difference Jacobian, started from a short simulation. Its eigenvalues are the orbit's Floquet
multipliers. Every trajectory is integrated by the core Simulator (implicit Coulomb stick/slip; its
substeps in C where furuta_rt.sim.compiled covers the model).

Two loops are supported, both deterministic (no sensor noise, no quantisation):

* ``IdealLoop``: u = L·x from the exact state, recomputed every 0.1 ms (the continuous loop of
  section 4, the describing function's own loop);
* ``SampledLoop``: the rig's loop — the Controller (φ̇ observer, command delay, saturation) at the
  loop rate, fed by the Bessel path's θ_f, θ̇_f and the exact φ. Restarting it on the section resets the
  sampling phase, so its orbit is exact only up to O(h) in timing (h = loop period).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from furuta_rt.config import CompMode, RigConfig
from furuta_rt.controller.controller import Controller, Measurement
from furuta_rt.model.effects import Effects
from furuta_rt.model.rig import RigModel
from furuta_rt.sim.compiled import fast_simulator

STATE_LABELS = ("theta", "theta_dot", "phi", "phi_dot")


class IdealLoop:
    """u = L·x of the exact state every ``1/rate_hz`` s on the nonlinear plant with the rig's friction."""

    name = "ideal"
    fd_rel = 1e-3  # finite-difference step relative to the orbit's size

    def __init__(
        self, rig: RigConfig, gains: np.ndarray | list[float], effects: Effects | None = None, rate_hz: float = 10_000.0
    ) -> None:
        model = replace(RigModel.from_config(rig, effects), bessel=None, theta_noise=0.0, theta_dot_noise=0.0)
        self.sim = fast_simulator(model, rate_hz, rate_hz)
        self.gains = np.asarray(gains, dtype=float)
        self._l = tuple(float(g) for g in self.gains)  # as floats: the same products, no numpy scalar per step
        # φ is cyclic (the dynamics do not depend on it) without φ feedback or cable spring: an orbit
        # may then drift in φ, and φ is left out of the periodicity condition.
        self.cyclic: tuple[int, ...] = (2,) if self.gains[2] == 0.0 and model.spring_k == 0.0 else ()
        self.dt = 1.0 / rate_hz
        self._lugre = model.arm_friction.lugre is not None
        self.u = 0.0

    def get(self) -> np.ndarray:
        s = self.sim
        return np.array([s.theta, s.theta_dot, s.phi, s.phi_dot] + ([s.z] if self._lugre else []))

    def set(self, x: np.ndarray) -> None:
        s = self.sim
        s.theta, s.theta_dot, s.phi, s.phi_dot = (float(v) for v in x[:4])
        if self._lugre:
            s.z = float(x[4])
        s.stuck = False  # re-detected in the next substep if φ̇ = 0 and the arm is held

    def step(self) -> None:
        s = self.sim
        l1, l2, l3, l4 = self._l
        self.u = l1 * s.theta + l2 * s.theta_dot + l3 * s.phi + l4 * s.phi_dot
        s.set_command(self.u)
        s.advance(1)


class SampledLoop:
    """The Controller at the loop rate on the simulator (Bessel θ path, observer, command delay,
    saturation, compensation ``mode``), without noise or quantisation."""

    name = "sampled"
    fd_rel = 1e-2  # larger: the map is rough at the O(h) scale of the sampling phase

    def __init__(
        self,
        rig: RigConfig,
        gains: np.ndarray | list[float] | None = None,
        effects: Effects | None = None,
        mode: CompMode = "none",
    ) -> None:
        model = replace(RigModel.from_config(rig, effects), theta_noise=0.0, theta_dot_noise=0.0)
        self.sim = fast_simulator(model, rig.control.rate_hz)
        self.ctrl = Controller.from_rig(rig, mode=mode, gains=gains)
        self.ctrl.reset(0.0)
        self._comp_state = self.ctrl.compensator.mode == "lugre"
        self.cyclic: tuple[int, ...] = ()
        self.dt = 1.0 / rig.control.rate_hz
        self._lugre = model.arm_friction.lugre is not None
        self.u = 0.0
        # the latency rule: the command acts from its sample instant (a command_latency: the delay line carries it)
        # or from the next sample (the driver's tick; more ticks are not followed here: the state would hold a queue)
        self._at_sample = model.command_timing(rig.control.command_delay_ticks)[0] == 0

    def get(self) -> np.ndarray:
        s, c = self.sim, self.ctrl
        return np.array(
            [s.theta, s.theta_dot, s.phi, s.phi_dot, s.y, s.y_dot, s.command, c.observer.phi, c.observer.phi_dot]
            + list(c.pending_torques)  # the net torques still in the command pipeline (observer input)
            + ([s.z] if self._lugre else [])
            + ([c.compensator.z] if self._comp_state else [])
        )

    def set(self, x: np.ndarray) -> None:
        s, c = self.sim, self.ctrl
        s.theta, s.theta_dot, s.phi, s.phi_dot, s.y, s.y_dot, s.command = (float(v) for v in x[:7])
        c.observer.phi, c.observer.phi_dot = float(x[7]), float(x[8])
        n_pending = len(c.pending_torques)
        c.set_pending_torques(x[9 : 9 + n_pending])
        k = 9 + n_pending
        if self._lugre:
            s.z = float(x[k])
            k += 1
        if self._comp_state:
            c.compensator.z = float(x[k])
        s.stuck = False

    def step(self) -> None:
        s = self.sim
        y, yd = s.filtered_theta()
        out = self.ctrl.update(Measurement(s.t, y, yd, s.phi))
        if self._at_sample:
            s.set_command(out.u)
            s.advance(1)
        else:
            s.advance(1)
            s.set_command(out.u)
        self.u = out.u


Loop = IdealLoop | SampledLoop


class OrbitNotFound(RuntimeError):
    """No periodic orbit: the loop settles, drifts or falls."""


@dataclass(frozen=True)
class Trajectory:
    """States [θ, θ̇, φ, φ̇], command u and stuck flag sampled every loop step."""

    t: np.ndarray
    x: np.ndarray
    u: np.ndarray
    stuck: np.ndarray


def record_trajectory(loop: Loop, steps: int) -> Trajectory:
    t = np.arange(steps + 1) * loop.dt
    x: list[tuple[float, float, float, float]] = []  # lists, made arrays once at the end
    u: list[float] = []
    stuck: list[bool] = []
    s = loop.sim
    for k in range(steps + 1):
        x.append((s.theta, s.theta_dot, s.phi, s.phi_dot))
        stuck.append(s.stuck)
        if k < steps:
            loop.step()
        u.append(loop.u)
    return Trajectory(t, np.array(x, dtype=float).reshape(steps + 1, 4), np.array(u, dtype=float),
                      np.array(stuck, dtype=bool))


def _to_section(loop: Loop, count: int, max_time: float, fall: float) -> tuple[np.ndarray, float]:
    """Step until θ has crossed zero upwards ``count`` times; the loop state there (linearly
    interpolated between steps) and the time taken."""
    n_max = int(max_time / loop.dt)
    prev = loop.get()
    seen = 0
    for k in range(n_max):
        loop.step()
        cur = loop.get()
        if abs(cur[0]) > fall:
            raise OrbitNotFound(f"the pendulum fell (|θ| > {fall} rad)")
        if prev[0] < 0.0 <= cur[0]:
            seen += 1
            if seen == count:
                s = -prev[0] / (cur[0] - prev[0])
                return prev + s * (cur - prev), (k + s) * loop.dt
        prev = cur
    raise OrbitNotFound(f"no upward θ crossing within {max_time:g} s (the loop settles or drifts)")


@dataclass(frozen=True)
class OrbitStats:
    """Period and amplitudes (half peak-to-peak) and standard deviations over whole periods.
    ``amplitude["phi_dot"]`` is half the peak-to-peak of φ̇ (its peak for a symmetric orbit)."""

    period: float
    amplitude: dict[str, float]
    std: dict[str, float]
    stuck_fraction: float
    drift_phi_dot: float = 0.0  # mean arm velocity over the period (rad/s)

    def to_dict(self) -> dict:
        return {
            "period_s": self.period,
            "frequency_rad_s": 2 * math.pi / self.period,
            "amplitude": self.amplitude,
            "std": self.std,
            "stuck_fraction": self.stuck_fraction,
            "drift_phi_dot": self.drift_phi_dot,
        }


def _stats(tr: Trajectory, period: float) -> OrbitStats:
    """Amplitudes and stds over whole periods; φ with its mean drift (if any) removed."""
    x = tr.x.copy()
    drift = float((x[-1, 2] - x[0, 2]) / (tr.t[-1] - tr.t[0])) if len(tr.t) > 1 else 0.0
    x[:, 2] -= drift * (tr.t - tr.t[0])
    amp = {name: float(np.ptp(x[:, i]) / 2) for i, name in enumerate(STATE_LABELS)}
    amp["u"] = float(np.ptp(tr.u) / 2)
    std = {name: float(np.std(x[:, i])) for i, name in enumerate(STATE_LABELS)}
    std["u"] = float(np.std(tr.u))
    return OrbitStats(period, amp, std, float(np.mean(tr.stuck)), drift)


@dataclass(frozen=True)
class PeriodicOrbit:
    loop: str
    stats: OrbitStats
    trajectory: Trajectory
    section_state: np.ndarray
    crossings_per_period: int
    residual: float  # ‖P(x*) − x*‖ relative to the orbit's size
    iterations: int
    stable: bool
    stability_method: str
    multipliers: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def to_dict(self) -> dict:
        return {
            "loop": self.loop,
            **self.stats.to_dict(),
            "crossings_per_period": self.crossings_per_period,
            "residual": self.residual,
            "newton_iterations": self.iterations,
            "floquet_multipliers_abs": sorted((float(abs(m)) for m in self.multipliers), reverse=True),
            "stable": self.stable,
            "stability_method": self.stability_method,
        }


def find_periodic_orbit(
    loop: Loop,
    x0: tuple[float, float, float, float] = (0.05, 0.0, 0.0, 0.0),
    *,
    warmup_crossings: int = 6,
    max_period: float = 30.0,
    tol: float = 1e-7,
    accept: float = 1e-3,
    max_iter: int = 12,
    fd_rel: float | None = None,
    fall: float = 1.0,
) -> PeriodicOrbit:
    """Newton shooting on the θ = 0 upward section, started from a short simulation from ``x0``.

    Converges to ``tol`` (relative to the orbit's size) or to the map's roughness floor; raises
    OrbitNotFound if the residual stays above ``accept``."""
    base = loop.get()
    base[:4] = x0
    loop.set(base)
    # Warm-up: a few crossings bring the state near the attracting orbit and tell how many
    # crossings make one period.
    pts = []
    x = loop.get()
    for _ in range(warmup_crossings):
        x, _ = _to_section(loop, 1, max_period, fall)
        pts.append(x)
    oscale = _orbit_scale(pts)
    last = pts[-1]
    free = np.array([i for i in range(1, len(last)) if i not in loop.cyclic])  # θ = 0 on the section
    m, best = 1, math.inf
    for cand in (1, 2, 3):
        d = float(np.max(np.abs(pts[-1][free] - pts[-1 - cand][free]) / oscale[free]))
        if d < 0.5 * best:
            m, best = cand, d

    def residual(z: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        x = last.copy()
        x[0] = 0.0
        x[free] = z
        loop.set(x)
        xn, T = _to_section(loop, m, max_period * m, fall)
        return (xn[free] - z), xn, T

    def jacobian(z: np.ndarray, r: np.ndarray, rel: float) -> np.ndarray:
        """DP − I by forward differences with steps ``rel`` times the orbit's size."""
        h = rel * oscale[free]
        J = np.empty((len(z), len(z)))
        for j in range(len(z)):
            dz = np.zeros(len(z))
            dz[j] = h[j]
            J[:, j] = (residual(z + dz)[0] - r) / h[j]
        return J

    def size(r: np.ndarray) -> float:
        return float(np.max(np.abs(r) / oscale[free]))

    base_rel = fd_rel or loop.fd_rel
    z = last[free].copy()
    r, xn, _ = residual(z)
    iterations = 0
    while iterations < max_iter and size(r) >= tol:
        iterations += 1
        # steps no smaller than the current error: the map is only piecewise smooth at the
        # substep (and sampling) scale, so tiny steps would difference its roughness
        J = jacobian(z, r, max(base_rel, size(r)))
        try:
            step = np.linalg.solve(J, -r)
        except np.linalg.LinAlgError:
            step = xn[free] - z
        lam, accepted = 1.0, False
        for _ in range(4):
            try:
                r_new, xn_new, _ = residual(z + lam * step)
            except OrbitNotFound:
                lam *= 0.5
                continue
            if size(r_new) < size(r):
                accepted = True
                break
            lam *= 0.5
        if not accepted:
            # Newton stalls at the map's own roughness (stick/slip decided per substep, sampling
            # phase): try one plain iteration of the map, else stop at this floor.
            step, lam = xn[free] - z, 1.0
            r_new, xn_new, _ = residual(xn[free])
            if size(r_new) >= size(r):
                break
        z = z + lam * step
        r, xn = r_new, xn_new
    if size(r) > accept:
        raise OrbitNotFound(
            f"shooting did not converge (relative residual {size(r):.1e} after {iterations} Newton steps): no periodic "
            "orbit near the simulated trajectory, whose amplitude keeps changing"
        )
    if size(r) < 1e-6:
        multipliers = np.linalg.eigvals(jacobian(z, r, base_rel) + np.eye(len(z)))
        stable = bool(np.all(np.abs(multipliers) < 1.0))
        stability = "Floquet multipliers"
    else:
        # Converged only to the map's roughness floor (stick/slip and saturation switching at tick or
        # substep instants): differenced multipliers would be noise; iterate from a perturbed start.
        multipliers = np.zeros(0)
        stable = _attracts(residual, z, free, oscale, size, 20.0 * size(r) + 1e-3)
        stability = "perturbed iterations"
    # Record one period from the fixed point.
    x = last.copy()
    x[0] = 0.0
    x[free] = z
    loop.set(x)
    _, T = _to_section(loop, m, max_period * m, fall)
    loop.set(x)
    tr = record_trajectory(loop, max(2, round(T / loop.dt)))
    return PeriodicOrbit(
        loop=loop.name,
        stats=_stats(tr, T),
        trajectory=tr,
        section_state=x,
        crossings_per_period=m,
        residual=size(r),
        iterations=iterations,
        stable=stable,
        stability_method=stability,
        multipliers=multipliers,
    )


def _attracts(residual, z: np.ndarray, free: np.ndarray, oscale: np.ndarray, size, delta: float, n: int = 8) -> bool:
    """Does the map keep a start ``delta`` (relative) off the fixed point near it? Near: within half the
    initial offset, or within 5% of the orbit's size (the sampled loop's map is rough at the ~1% level:
    a tick more or less of stick or saturation)."""
    zi = z + delta * oscale[free] * np.sign(np.arange(len(z)) % 2 - 0.5)
    d0 = size(zi - z)
    dev = []
    try:
        for _ in range(n):
            _, xi, _ = residual(zi)
            zi = xi[free]
            dev.append(size(zi - z))
    except OrbitNotFound:
        return False
    return max(dev[n // 2:]) < max(0.5 * d0, 0.05)


def _orbit_scale(pts: list[np.ndarray]) -> np.ndarray:
    """Per-coordinate size of the orbit from the warm-up crossings (for tolerances and FD steps)."""
    a = np.array(pts)
    s = np.maximum(np.max(np.abs(a), axis=0), np.ptp(a, axis=0))
    return np.maximum(s, 1e-6 * max(float(np.max(s)), 1e-12))


def simulate_limit_cycle(
    loop: Loop,
    x0: tuple[float, float, float, float] = (0.05, 0.0, 0.0, 0.0),
    duration: float = 60.0,
    transient: float = 20.0,
    crossings_per_period: int = 1,
) -> tuple[OrbitStats, Trajectory]:
    """Long simulation of the same loop: the mean period between upward θ crossings after the
    transient, amplitudes and standard deviations over the whole periods recorded."""
    base = loop.get()
    base[:4] = x0
    loop.set(base)
    tr = record_trajectory(loop, round(duration / loop.dt))
    th = tr.x[:, 0]
    k0 = round(transient / loop.dt)
    idx = np.nonzero((th[k0:-1] < 0.0) & (th[k0 + 1 :] >= 0.0))[0] + k0
    if len(idx) < crossings_per_period + 1:
        raise OrbitNotFound(f"fewer than two periods after {transient:g} s of transient: no sustained limit cycle")
    tc = tr.t[idx] - th[idx] * loop.dt / (th[idx + 1] - th[idx])
    m = crossings_per_period
    n_per = (len(idx) - 1) // m
    first, last = idx[0], idx[n_per * m]
    period = float((tc[n_per * m] - tc[0]) / n_per)
    window = Trajectory(tr.t[first:last], tr.x[first:last], tr.u[first:last], tr.stuck[first:last])
    return _stats(window, period), tr


def relative_errors(a: OrbitStats, b: OrbitStats) -> dict[str, float]:
    """(a − b)/b for the period and the amplitudes."""
    out = {"period": (a.period - b.period) / b.period}
    for k, v in b.amplitude.items():
        out[f"amplitude_{k}"] = (a.amplitude[k] - v) / v if v else math.nan
    return out
