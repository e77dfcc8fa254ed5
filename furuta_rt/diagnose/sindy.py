"""The off-the-shelf alternative for the benchmark: PySINDy (SINDy with control) on the same recordings.

SINDy regresses the state derivatives on a generic library; here polynomials of degree 1 (2 gives
dense nonsense under feedback) in [θ, θ̇, φ, φ̇, u] plus sgn(·) of each (friction-aware, to be generous), thresholded least
squares on normalised columns. Its input is what a careful user would give it: the measured θ_f, θ̇_f
and φ, φ̇ by smoothed differences, and the command shifted by the known one-tick latency.

SINDy names no physics. To score it beside ``diagnose``, the terms of its θ̈ and φ̈ equations that the
nominal linearisation (eq. 6: θ̈, φ̈ linear in θ and u) does not have are read as the effects they would
mean (sgn φ̇ in φ̈ → arm_coulomb, φ̇ → arm_viscous, φ → arm_spring, θ̇ in θ̈ → pendulum_viscous, a constant in
θ̈ → theta_offset, a changed u coefficient → input_gain / arm_inertia); an input delay has no term.
Benchmark-only: needs ``pip install pysindy`` (the ``bench`` extra).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from furuta_rt.config import RigConfig
from furuta_rt.model.plant import FurutaPlant
from furuta_rt.recording import Recording

NAMES = ["th", "thd", "ph", "phd"]


def available() -> bool:
    import importlib.util

    return importlib.util.find_spec("pysindy") is not None


@dataclass
class SindyResult:
    equations: dict[str, dict[str, float]]  # "thdd"/"phdd" → {term: coefficient}
    extra_terms: dict[str, dict[str, float]]  # terms beyond the nominal model
    named: dict[str, dict[str, float]]  # the effects those terms would mean, with parameters
    seconds: float


def fit_sindy(rec: Recording, rig: RigConfig, threshold: float = 0.2, degree: int = 1) -> SindyResult:
    import time

    import pysindy as ps

    t0 = time.perf_counter()
    dt = float(np.median(np.diff(rec.t)))
    th = np.asarray(rec.theta, float)
    thd = np.asarray(rec.theta_dot, float) if rec.theta_dot is not None else np.gradient(th, dt)
    ph = np.asarray(rec.phi, float)
    diff = ps.SmoothedFiniteDifference(smoother_kws={"window_length": 21, "polyorder": 3})
    phd = np.asarray(diff(ph, t=dt)).ravel()
    x = np.column_stack([th, thd, ph, phd])
    D = rig.control.command_delay_ticks
    u = np.concatenate([np.zeros(D), np.asarray(rec.u, float)[: len(rec.u) - D]])[:, None]
    sign_lib = ps.CustomLibrary(library_functions=[lambda s: np.sign(s)], function_names=[lambda s: f"sgn({s})"])
    lib = ps.GeneralizedLibrary([ps.PolynomialLibrary(degree=degree), sign_lib])
    model = ps.SINDy(feature_library=lib, optimizer=ps.STLSQ(threshold=threshold, normalize_columns=True),
                     differentiation_method=diff)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model.fit(x, t=dt, u=u, feature_names=[*NAMES, "u"])
    names = model.get_feature_names()
    coef = model.coefficients()
    eqs = {"thdd": dict(zip(names, coef[1], strict=True)), "phdd": dict(zip(names, coef[3], strict=True))}
    eqs = {k: {n: float(c) for n, c in v.items() if c != 0.0} for k, v in eqs.items()}
    extra, named = interpret(eqs, rig)
    return SindyResult(eqs, extra, named, time.perf_counter() - t0)


def interpret(eqs: dict[str, dict[str, float]], rig: RigConfig) -> tuple[dict, dict]:
    """Terms beyond eq. 6 and the named effects they would mean (parameters via eq. 6's input gains)."""
    plant = FurutaPlant(rig.lumped())
    A, B = plant.linearize()
    p = rig.lumped()
    b_arm = B[3, 0]  # φ̈ per N m on the arm
    b_pend = p.beta / p.zeta  # θ̈ per N m at the pendulum pivot, (M⁻¹)₁₁ at upright
    nominal = {"thdd": {"th", "u"}, "phdd": {"th", "u"}}
    extra = {k: {n: c for n, c in v.items() if n not in nominal[k]} for k, v in eqs.items()}
    named: dict[str, dict[str, float]] = {}
    ph_eq, th_eq = eqs["phdd"], eqs["thdd"]
    if "sgn(phd)" in ph_eq:
        named["arm_coulomb"] = {"Fc": -ph_eq["sgn(phd)"] / b_arm}
    if "phd" in ph_eq:
        named["arm_viscous"] = {"Fv": -ph_eq["phd"] / b_arm}
    if "ph" in ph_eq:
        k = -ph_eq["ph"] / b_arm
        named["arm_spring"] = {"k": k, "phi0": ph_eq.get("1", 0.0) / b_arm / k if k else 0.0}
    if "thd" in th_eq:
        named["pendulum_viscous"] = {"bp": -th_eq["thd"] / b_pend}
    if "1" in th_eq:
        named["theta_offset"] = {"offset": -th_eq["1"] / A[1, 0]}
    g = ph_eq.get("u", 0.0) / b_arm
    if abs(g - 1.0) > 0.05 and g > 0:
        named["input_gain"] = {"gain": g}
        J = rig.plant.arm_inertia
        named["arm_inertia"] = {"J": J + p.beta * (1.0 / g - 1.0)}
    return extra, named
