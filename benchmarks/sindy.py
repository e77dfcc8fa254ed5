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


@dataclass
class ResidualSindyResult:
    equations: dict[str, dict[str, float]]  # "pendulum"/"arm" → {term: coefficient (N m per unit of the term)}
    named: dict[str, dict[str, float]]  # the effects those terms would mean, with parameters
    seconds: float


def fit_sindy_residual(rec: Recording, rig: RigConfig, threshold: float = 0.2, sigma: float = 0.02) -> ResidualSindyResult:
    """Discrepancy modelling (Kaheman, Kaiser, Strom, Kutz & Brunton 2019): SINDy on what the nominal model leaves
    out. The residual is eq. 4's inverse dynamics (FurutaPlant.inverse_dynamics: the joint torques the measured
    motion needs) minus the nominal torques (the rig's actuator on the command held over its configured latency),
    regressed with the same candidates and thresholding as ``fit_sindy`` (degree-1 polynomials in θ, θ̇, φ, φ̇, u
    and sgn of each), each equation scaled to unit rms. To isolate the regression from the signal processing it
    gets the states ``diagnose`` uses (furuta_rt.diagnose.regression.states: θ through the inverse of the rig's θ path,
    derivatives and the held command through one Gaussian kernel of width ``sigma``). Its coefficients are
    torques, so they read directly as effects (an arm inertia error would need φ̈ among the candidates: like
    ``fit_sindy``, it has none; nor has it a delay)."""
    import time

    import pysindy as ps

    from furuta_rt.diagnose.regression.states import prepare
    from furuta_rt.model.rig import RigModel

    t0 = time.perf_counter()
    prep = prepare(rec, rig)
    st = prep.states(sigma)
    keep = prep.valid
    th, thd, thdd = st.theta[keep], st.theta_dot[keep], st.theta_ddot[keep]
    ph, phd, phdd = st.phi[keep], st.phi_dot[keep], st.phi_ddot[keep]
    u = st.held(prep.u, prep.command_lag)[keep]
    model = RigModel.from_config(rig)
    terms = np.array([model.actuator.torque_terms(float(v)) for v in u])
    tau_arm_nominal = terms[:, 0] - terms[:, 1] * phd
    tau_pend, tau_arm = model.plant.inverse_dynamics(th, thd, phd, thdd, phdd)
    residual = np.column_stack([np.zeros_like(th), tau_pend, np.zeros_like(th), tau_arm - tau_arm_nominal])
    # each equation in units of its own rms, so that the threshold means the same as in ``fit_sindy``
    scale = np.array([1.0, float(np.std(residual[:, 1])) or 1.0, 1.0, float(np.std(residual[:, 3])) or 1.0])
    residual = residual / scale
    x = np.column_stack([th, thd, ph, phd])
    sign_lib = ps.CustomLibrary(library_functions=[lambda s: np.sign(s)], function_names=[lambda s: f"sgn({s})"])
    lib = ps.GeneralizedLibrary([ps.PolynomialLibrary(degree=1), sign_lib])
    sindy = ps.SINDy(feature_library=lib, optimizer=ps.STLSQ(threshold=threshold, normalize_columns=True))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sindy.fit(x, t=prep.dt, x_dot=residual, u=u[:, None], feature_names=[*NAMES, "u"])
    names = sindy.get_feature_names()
    coef = sindy.coefficients() * scale[:, None]
    eqs = {"pendulum": dict(zip(names, coef[1], strict=True)), "arm": dict(zip(names, coef[3], strict=True))}
    eqs = {k: {n: float(c) for n, c in v.items() if c != 0.0} for k, v in eqs.items()}
    cos_sign = float(np.sign(np.mean(np.cos(th)))) or 1.0
    return ResidualSindyResult(eqs, interpret_residual(eqs, rig, cos_sign), time.perf_counter() - t0)


def interpret_residual(eqs: dict[str, dict[str, float]], rig: RigConfig, cos_sign: float = 1.0) -> dict:
    """The effects the residual's torque terms would mean: −c·sgn φ̇ → arm_coulomb, −c·φ̇ → arm_viscous, −k(φ − φ0)
    → arm_spring, a constant arm torque → arm_bias, c·u → input_gain 1 + c/(torque per command), −c·θ̇ →
    pendulum_viscous, −c·sgn θ̇ → pendulum_coulomb, a constant pendulum torque −ε·offset·cos θ → theta_offset."""
    arm, pend = eqs["arm"], eqs["pendulum"]
    a = rig.actuator
    per_command = 1.0 if a.kind == "torque" else a.Kt / a.R  # type: ignore[operator]
    named: dict[str, dict[str, float]] = {}
    if "sgn(phd)" in arm:
        named["arm_coulomb"] = {"Fc": -arm["sgn(phd)"]}
    if "phd" in arm:
        named["arm_viscous"] = {"Fv": -arm["phd"]}
    if "ph" in arm:
        k = -arm["ph"]
        named["arm_spring"] = {"k": k, "phi0": arm.get("1", 0.0) / k if k else 0.0}
    elif "1" in arm:
        named["arm_bias"] = {"tau": arm["1"]}
    if "u" in arm:
        named["input_gain"] = {"gain": 1.0 + arm["u"] / per_command}
    if "thd" in pend:
        named["pendulum_viscous"] = {"bp": -pend["thd"]}
    if "sgn(thd)" in pend:
        named["pendulum_coulomb"] = {"Fc": -pend["sgn(thd)"]}
    if "1" in pend:
        named["theta_offset"] = {"offset": -pend["1"] / (rig.lumped().epsilon * cos_sign)}
    return named
