"""Minimum-time swing-up with the actuator's bound, by trajectory optimisation (direct collocation with scipy): the
reference the energy swing-up (furuta_rt.controller.swingup) is compared with in scripts/bench.

    find the least T for which there are x_k = [θ, θ̇, φ, φ̇](t_k), commands u_k and accelerations (θ̈, φ̈)_k,
    t_k = k T / N, with
        eq. 4 at every node (FurutaPlant.inverse_dynamics: τ_pend = 0, τ_arm = the actuator's torque for u_k,
              a DC motor's Kt (u − Ke φ̇)/R),
        the collocation defects zero between nodes (trapezoidal velocities, Hermite-cubic angles),
        |u_k| ≤ limit (the same bound as the swing-up), |φ_k| ≤ phi_limit,
        x_0 hanging at rest [π, 0, 0, 0],  x_N inside the swing-up's catch region: |θ_N| (mod 2π) < catch_theta and
        |E_N| < catch_energy (the arm free) — the same end the energy swing-up's time to the catch is measured at.

For a fixed T this is a feasibility problem, solved by scipy.optimize.least_squares (trf, sparse Jacobian) from
the last feasible trajectory; T is bisected between an infeasible and a feasible one. The first feasible
trajectory comes from a simulated energy swing-up of the same rig up to its catch (sim/swingup_run). A local method:
the T found is an upper bound on the true minimum, so the ratio the benchmark reports is a lower bound on how far
the energy swing-up is from time-optimal. The nominal plant (no friction).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.optimize
import scipy.sparse

from furuta_rt.config import RigConfig
from furuta_rt.controller.swingup import SwingUpDesign
from furuta_rt.model.plant import FurutaPlant
from furuta_rt.model.rig import RigModel
from furuta_rt.sim.simulator import Simulator
from furuta_rt.sim.swingup_run import SwingUpRun, swing_up_rig

NODES_PER_HALF_PERIOD = 12
"""Collocation nodes per half period of the hanging pendulum (π √(α/ε))."""
FEASIBLE = 1e-5
"""Largest scaled defect (torques / ε, rad, rad/s) of a feasible trajectory."""


@dataclass(frozen=True)
class MinTimeSwingUp:
    T: float  # s (nan: no feasible trajectory)
    T_infeasible: float  # s: the longest T tried that had none
    nodes: int
    success: bool
    max_defect: float
    peak_phi: float  # rad
    peak_u: float
    open_loop_end: tuple[float, float] = (math.nan, math.nan)  # (|θ|, E/2ε) where the Simulator ends with its u


def _sparsity(N: int) -> scipy.sparse.lil_matrix:
    """Which variables each residual depends on (node k, and k+1 for the defects)."""
    n1 = N + 1
    S = scipy.sparse.lil_matrix((2 * n1 + 4 * N + 5, 7 * n1), dtype=int)
    for k in range(n1):
        for j in (0, 1, 3, 4, 5, 6):  # θ, θ̇, φ̇, u, θ̈, φ̈ at node k
            S[k, j * n1 + k] = S[n1 + k, j * n1 + k] = 1
    for d, cols in enumerate(((0, 1, 5), (1, 5), (2, 3, 6), (3, 6))):
        for k in range(N):
            for j in cols:
                S[2 * n1 + d * N + k, j * n1 + k] = S[2 * n1 + d * N + k, j * n1 + k + 1] = 1
    base = 2 * n1 + 4 * N
    for i, (j, k) in enumerate(((0, 0), (1, 0), (2, 0), (3, 0), (0, N))):
        S[base + i, j * n1 + k] = 1
    S[base + 4, n1 + N] = 1  # the end energy: θ_N and θ̇_N
    return S


def optimise(rig: RigConfig, guess: SwingUpRun, bisections: int = 6, max_nfev: int = 100) -> MinTimeSwingUp:
    """The minimum-time swing-up of ``rig`` (module docstring), starting from ``guess`` up to its catch."""
    plant = FurutaPlant(rig.lumped())
    p = plant.p
    a = rig.actuator
    dc = a.kind == "dc_motor"
    lim, phi_lim, eps = a.limit, rig.safety.phi_limit, p.epsilon
    T0 = guess.first_catch_s
    half_period = math.pi * math.sqrt(p.alpha / p.epsilon)
    N = max(20, round(NODES_PER_HALF_PERIOD * T0 / half_period))
    n1 = N + 1
    k_end = int(np.searchsorted(guess.t, T0))
    s = np.linspace(0.0, 1.0, n1)
    src = guess.t[: k_end + 1] / guess.t[k_end]
    x = guess.true_state[: k_end + 1]  # the simulator's own states: smooth (the measured ones carry quantisation)
    theta_end = 2 * math.pi * round(x[-1, 0] / (2 * math.pi))  # the upright the guess went to
    th, thd, ph, phd = (np.interp(s, src, x[:, i]) for i in range(4))
    ph = np.clip(ph, -phi_lim, phi_lim)
    u = np.clip(np.interp(s, src, np.concatenate([[0.0], guess.u[:k_end]])), -lim, lim)  # u acts a tick later
    z = np.concatenate([th, thd, ph, phd, u, np.gradient(thd, s * T0), np.gradient(phd, s * T0)])

    def split(z: np.ndarray) -> list[np.ndarray]:
        return [z[i * n1: (i + 1) * n1] for i in range(7)]

    def residuals(z: np.ndarray, T: float) -> np.ndarray:
        th, thd, ph, phd, u, thdd, phdd = split(z)
        h = T / N
        tau_p, tau_a = plant.inverse_dynamics(th, thd, phd, thdd, phdd)
        torque = a.Kt * (u - a.Ke * phd) / a.R if dc else u  # type: ignore[operator]
        d_thd = thd[1:] - thd[:-1] - 0.5 * h * (thdd[1:] + thdd[:-1])
        d_phd = phd[1:] - phd[:-1] - 0.5 * h * (phdd[1:] + phdd[:-1])
        d_th = th[1:] - th[:-1] - 0.5 * h * (thd[1:] + thd[:-1]) - h * h / 12.0 * (thdd[:-1] - thdd[1:])
        d_ph = ph[1:] - ph[:-1] - 0.5 * h * (phd[1:] + phd[:-1]) - h * h / 12.0 * (phdd[:-1] - phdd[1:])
        energy = float(plant.energy(th[-1], thd[-1], 0.0)) - eps
        ends = [th[0] - math.pi, thd[0], ph[0], phd[0], max(0.0, abs(energy) - catch_energy) / eps]
        return np.concatenate([tau_p / eps, (tau_a - torque) / eps, d_th, d_thd, d_ph, d_phd, ends])

    sparsity = _sparsity(N)
    free = np.full(n1, np.inf)
    hi = np.concatenate([free, free, np.full(n1, phi_lim), free, np.full(n1, lim), free, free])
    lo = -hi
    d = SwingUpDesign.from_rig(swing_up_rig(rig))
    catch_energy = d.catch_energy
    hi[N], lo[N] = theta_end + d.catch_theta, theta_end - d.catch_theta  # θ_N inside the catch angle
    def solve(T: float, z0: np.ndarray) -> tuple[np.ndarray, float]:
        r = scipy.optimize.least_squares(residuals, np.clip(z0, lo, hi), jac_sparsity=sparsity, bounds=(lo, hi),
                                         args=(T,), method="trf", xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=max_nfev)
        return r.x, float(np.max(np.abs(residuals(r.x, T))))

    def rescale(z: np.ndarray, T_from: float, T_to: float) -> np.ndarray:
        th, thd, ph, phd, u, thdd, phdd = split(z)
        k = T_from / T_to
        return np.concatenate([th, thd * k, ph, phd * k, u, thdd * k * k, phdd * k * k])

    T_hi = T0
    z_hi, err = solve(T_hi, z)
    while err > FEASIBLE and T_hi < 1.5 * T0:  # the discretised guess may need a little more time
        T_hi *= 1.1
        z_hi, err = solve(T_hi, rescale(z_hi, T_hi / 1.1, T_hi))
    if err > FEASIBLE:
        return MinTimeSwingUp(math.nan, T_hi, N, False, err, math.nan, math.nan)
    T_lo = 0.3 * T0
    for _ in range(bisections):
        T_mid = 0.5 * (T_lo + T_hi)
        z_mid, err = solve(T_mid, rescale(z_hi, T_hi, T_mid))
        if err <= FEASIBLE:
            T_hi, z_hi = T_mid, z_mid
        else:
            T_lo = T_mid
    th, thd, ph, phd, u, _, _ = split(z_hi)
    return MinTimeSwingUp(T=T_hi, T_infeasible=T_lo, nodes=N, success=True,
                          max_defect=float(np.max(np.abs(residuals(z_hi, T_hi)))),
                          peak_phi=float(np.max(np.abs(ph))), peak_u=float(np.max(np.abs(u))),
                          open_loop_end=_open_loop_end(rig, T_hi, u))


def _open_loop_end(rig: RigConfig, T: float, u: np.ndarray) -> tuple[float, float]:
    """Where the Simulator (nominal rig, 10 kHz, no noise) ends when driven open loop by the optimum's command
    (linear between the nodes): (|θ| wrapped, E / 2ε). A check of the collocation's accuracy against eq. 4 as the
    simulator integrates it (open loop: errors grow near upright)."""
    rate = 10_000.0
    sim = Simulator(RigModel.from_config(rig), rate, rate, x0=(math.pi, 0.0, 0.0, 0.0))
    grid = np.linspace(0.0, T, len(u))
    for k in range(round(T * rate)):
        sim.set_command(float(np.interp((k + 0.5) / rate, grid, u)))
        sim.advance()
    p = rig.lumped()
    energy = float(sim.model.plant.energy(sim.theta, sim.theta_dot, 0.0)) - p.epsilon
    return abs((sim.theta + math.pi) % (2 * math.pi) - math.pi), energy / (2 * p.epsilon)
