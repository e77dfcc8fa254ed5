"""Joint calibration of the arm's nominal parameters, and what the data pins (JSON key ``identification``).

The arm row of eq. 4 with the actuator of furuta_rt.model.actuator reads M22(θ; J) φ̈ + P = g·k_u·u_held − D·φ̇ + F,
P the pendulum's reaction and velocity terms, k_u = Kt/R for a DC motor (1 for a torque command), D the damping
(back-EMF Kt·Ke/R plus viscous friction), F the other selected effects. Its residual is linear in the departures of
the three parameters the data most often disputes — input gain g, arm inertia J (ID is linear in J), damping D — so
they are fitted jointly by least squares on top of the selected model, on the same held-out time blocks, and their
jackknife over the blocks gives each one's standard error and their correlations.

A parameter is *pinned* when its relative standard error is below PINNED_REL_SE and it is not collinear with another
(|correlation of the least-squares estimates| < COLLINEAR), unless its error is below a tenth of that anyway.
Scaling g, J and D together changes only P's share of the
residual, so when the pendulum's reaction is small the three are collinear and only their ratios are pinned: the
combinations reported with their own jackknife errors — the arm's acceleration per command unit g·k_u/J_eff, its
time constant J_eff/D and the steady speed per command unit g·k_u/D (``speed_per_volt`` for a DC motor, else
``speed_per_command``, where the damping is positive; J_eff: M22 averaged over the rows).
"""

from __future__ import annotations

import numpy as np

from furuta_rt.diagnose.regression.fitting import Stats, fit
from furuta_rt.diagnose.regression.library import ARM, Context
from furuta_rt.diagnose.regression.selection import EquationModel, Evaluation
from furuta_rt.model.friction import Viscous

PINNED_REL_SE = 0.1
COLLINEAR = 0.99


def _jackknife(values: np.ndarray) -> float:
    """Blocked-jackknife standard error of per-fold estimates."""
    v = values[np.isfinite(values)]
    B = len(v)
    return float(np.sqrt((B - 1) / B * np.sum((v - v.mean()) ** 2))) if B > 1 else float("inf")


def identification(em: EquationModel, selected: Evaluation) -> dict | None:
    """{parameters: {name: {value, se, pinned}}, combinations: {name: {value, se, unit}}} for the arm equation of
    ``selected`` (None when that equation has too few rows or no command to calibrate against)."""
    ctx: Context = em.ctx
    if em.equation != ARM or em.n_rows < 20 * em.th.n_blocks or not ctx.prep.commanded:
        return None
    spec = selected.spec
    X, owners = em.design(spec)
    owned = dict(owners)
    y = em.target(spec)
    a = ctx.arm
    extra: dict[str, np.ndarray] = {}
    if "input_gain" not in owned:
        extra["input_gain"] = ctx.command_torque(spec.path)
    if "arm_viscous" not in owned:
        extra["arm_viscous"] = Viscous(1.0).torque(a.phi_dot)
    extra["arm_inertia"] = -ctx.arm_dJ
    cols = [X] + [c[:, None] for c in extra.values()]
    k0 = X.shape[1]
    index = {**{n: owned[n].start for n in ("input_gain", "arm_viscous") if n in owned},
             **{n: k0 + i for i, n in enumerate(extra)}}
    w = ctx.arm_weight(spec.d_inertia)
    Xa = np.column_stack(cols) * np.asarray(w if np.ndim(w) else np.full(len(y), w))[:, None]
    st = Stats.of(y * w, Xa, em.blocks)
    f = fit(st)

    gain0, k_u = ctx.known_gain, _command_scale(ctx)
    fv0 = ctx.known_value("arm_viscous", "Fv")
    J0 = ctx.base_inertia + spec.d_inertia
    rows = em.row_mask
    m22 = float(np.mean(ctx.arm_m22[rows])) + spec.d_inertia

    def values(c: np.ndarray) -> dict[str, float]:
        g = gain0 * (1.0 + c[index["input_gain"]])
        fv = fv0 + c[index["arm_viscous"]]
        dJ = c[index["arm_inertia"]]
        damping = ctx.back_emf + fv
        J_eff = m22 + dJ
        out = {"input_gain": g, "arm_inertia": J0 + dJ, "arm_viscous": fv, "arm_damping": damping,
               "acceleration_per_command": g * k_u / J_eff,
               "time_constant": J_eff / damping if damping > 0 else float("nan")}
        speed = g * k_u / damping if damping > 0 else float("nan")
        if ctx.model.actuator.kind == "dc_motor":
            out["torque_per_volt"] = g * k_u
            out["speed_per_volt"] = speed
        else:  # a torque command: the steady speed per N m commanded (the same ratio of gain and damping)
            out["speed_per_command"] = speed
        return out

    full = values(f.coef)
    folds = [values(c) for c in f.fold_coef]
    se = {k: _jackknife(np.array([fo[k] for fo in folds])) for k in full}
    corr = _correlations(st, index)
    chosen = _selected_values(selected, ctx, k_u)
    params: dict[str, dict] = {}
    names = ["input_gain", "arm_inertia", "arm_viscous", "arm_damping"]
    if "torque_per_volt" in full:
        names.insert(1, "torque_per_volt")
    for name in names:
        v, s = full[name], se[name]
        rel = s / abs(v) if v else float("inf")
        linked = corr.get(_coef_of(name), {})
        partner = max(linked, key=lambda n: abs(linked[n]), default=None)
        collinear = partner is not None and abs(linked[partner]) >= COLLINEAR and rel >= PINNED_REL_SE / 10
        params[name] = {"value": v, "se": s, "pinned": bool(rel < PINNED_REL_SE and not collinear), "selected": False}
        if name in chosen:  # one source of truth: a parameter the effects report is reported with their value
            params[name].update(value=chosen[name][0], se=chosen[name][1], selected=True, joint={"value": v, "se": s})
        if partner is not None:
            params[name]["most_correlated"] = {"name": _param_of(partner, ctx), "r": linked[partner]}
    unit_u = "V" if ctx.model.actuator.kind == "dc_motor" else "N m"
    combos = {"acceleration_per_command": f"rad/s² per {unit_u}", "time_constant": "s"}
    if "speed_per_volt" in full:
        combos["speed_per_volt"] = "rad/s per V"
    if "speed_per_command" in full and np.isfinite(full["speed_per_command"]):
        combos["speed_per_command"] = "rad/s per N m"
    combinations = {n: {"value": full[n], "se": se[n], "unit": unit} for n, unit in combos.items()}
    unphysical = _unphysical(full)
    if unphysical:  # the joint fit traded the three against the pendulum's reaction: nothing of it is pinned
        for p in params.values():
            p["pinned"] = False
        combinations = {}
    return {"parameters": params, "combinations": combinations, "inertia_at_rows": m22,
            **({"unphysical": unphysical} if unphysical else {}),
            "method": "arm equation: input gain, arm inertia and damping fitted jointly with the selected effects "
                      "(value, se: the selected effects' own where they contain the parameter, the joint fit under "
                      "'joint'; pinned and the combinations: the joint fit); se: jackknife over the held-out time blocks"}


def _unphysical(joint: dict[str, float]) -> str:
    """Why the joint fit's gain, arm inertia or damping is impossible (≤ 0), or '' when none is. Such a fit (a balancing
    recording where the arm barely moves: an arm inertia of −3.2e-5 kg m² with a gain of 0.62, whose 'pinned' speed
    per volt comes out 37 ± 1.4 against a true 24) pins nothing: its combinations are not reported."""
    bad = [f"{name.replace('_', ' ')} {joint[name]:.3g}" for name in ("input_gain", "arm_inertia", "arm_damping")
           if not joint[name] > 0]
    return ("the joint fit gives " + ", ".join(bad) + " (≤ 0, impossible): this recording does not pin the arm's gain, "
            "inertia and damping, nor their combinations") if bad else ""


COMBINATION_MEMBERS: dict[str, tuple[str, str]] = {  # the two parameters (effect names) each combination ties together
    "acceleration_per_command": ("input_gain", "arm_inertia"),
    "time_constant": ("arm_inertia", "arm_viscous"),
    "speed_per_volt": ("input_gain", "arm_viscous"),
    "speed_per_command": ("input_gain", "arm_viscous"),
}
PINNABLE_PAIRS = (("input_gain", "arm_viscous"),)  # linear arm effects whose ratio is a physical combination (speed per volt)


def _selected_values(selected: Evaluation, ctx: Context, k_u: float) -> dict[str, tuple[float, float]]:
    """{identification name: (value, se)} of the parameters the selected effects contain, as the effects report them."""
    p, se, out = selected.params, selected.se, {}
    if "input_gain" in p:
        g, s = p["input_gain"]["gain"], se.get("input_gain", {}).get("gain", float("nan"))
        out["input_gain"] = (g, s)
        if ctx.model.actuator.kind == "dc_motor":
            out["torque_per_volt"] = (g * k_u, s * k_u)
    if "arm_viscous" in p:
        fv, s = p["arm_viscous"]["Fv"], se.get("arm_viscous", {}).get("Fv", float("nan"))
        out["arm_viscous"] = (fv, s)
        out["arm_damping"] = (ctx.back_emf + fv, s)
    if "arm_inertia" in p:
        out["arm_inertia"] = (p["arm_inertia"]["J"], se.get("arm_inertia", {}).get("J", float("nan")))
    return out


def collinear_pairs(em: EquationModel, ev: Evaluation) -> list[tuple[str, str]]:
    """The PINNABLE_PAIRS in ``ev`` whose least-squares estimates are collinear (|r| ≥ COLLINEAR): the data pins their
    combination, not each one."""
    pairs = [p for p in PINNABLE_PAIRS if em.equation == ARM and set(p) <= set(ev.spec.effects)]
    if not pairs:
        return []
    st, owners = em.stats(ev.spec)
    corr = _correlations(st, {n: sl.start for n, sl in owners if sl.stop > sl.start})
    return [p for p in pairs if abs(corr.get(p[0], {}).get(p[1], 0.0)) >= COLLINEAR]


def pinning(ident: dict | None, name: str) -> tuple[bool, list[dict]]:
    """(whether the data pins effect ``name``'s parameter alone; when not, the pinned combinations it enters, each
    {name, value, se, unit, members}) from an identification; (True, []) for effects it does not calibrate."""
    if ident is None or name not in ("input_gain", "arm_viscous", "arm_inertia"):
        return True, []
    par = ident["parameters"][name]
    if par["pinned"]:
        return True, []
    combos = [
        {"name": c, **v, "members": list(COMBINATION_MEMBERS[c])}
        for c, v in ident["combinations"].items()
        if name in COMBINATION_MEMBERS[c] and np.isfinite(v["value"]) and v["value"]
        and v["se"] < PINNED_REL_SE * abs(v["value"])
    ]
    return False, combos


def _command_scale(ctx: Context) -> float:
    """Torque per command unit of the nominal actuator at unit gain (Kt/R for a DC motor, 1 for a torque command)."""
    motor = ctx.model.actuator.motor
    return motor.torque_per_volt if motor is not None else 1.0


def _coef_of(name: str) -> str:
    return {"torque_per_volt": "input_gain", "arm_damping": "arm_viscous"}.get(name, name)


def _param_of(coef: str, ctx: Context) -> str:
    if coef == "input_gain" and ctx.model.actuator.kind == "dc_motor":
        return "torque_per_volt"
    return {"arm_viscous": "arm_damping"}.get(coef, coef)


def _correlations(st: Stats, index: dict[str, int]) -> dict[str, dict[str, float]]:
    """Correlations of the least-squares estimates of the calibrated coefficients (gain, viscous, inertia): the
    normalised inverse of the Gram matrix of all the columns (the others' share of each column taken out)."""
    G = st.G.sum(0)
    cov = np.linalg.pinv(G + 1e-12 * np.trace(G) / len(G) * np.eye(len(G)))
    names = list(index)
    idx = [index[n] for n in names]
    d = np.sqrt(np.clip(np.diag(cov)[idx], 1e-300, None))
    C = cov[np.ix_(idx, idx)] / np.outer(d, d)
    return {a: {b: float(C[i, j]) for j, b in enumerate(names) if j != i} for i, a in enumerate(names)}
