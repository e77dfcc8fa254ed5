"""The limit-cycle report of ``furuta-rt analyze limit-cycle``: the describing function (section 4)
beside the periodic orbit of the nonlinear loop and a long simulation of that same loop."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from furuta_rt.analysis.describing_function import (
    SECTION4_CASES,
    LimitCycleAnalysis,
    analyze_limit_cycle,
    sampled_limit_cycle,
)
from furuta_rt.analysis.periodic_orbit import (
    IdealLoop,
    OrbitNotFound,
    SampledLoop,
    find_periodic_orbit,
    relative_errors,
    simulate_limit_cycle,
)
from furuta_rt.config import RigConfig
from furuta_rt.controller.controller import design_gains
from furuta_rt.controller.loop_analysis import analyze
from furuta_rt.model.effects import Effects
from furuta_rt.model.plant import FurutaPlant

DEFAULT_FC = 1.0  # the thesis' section 4 uses Fc = 1


def default_fc(rig: RigConfig) -> tuple[float, str]:
    """Coulomb level to analyse: the rig's known arm friction, else its Coulomb compensation level,
    else the thesis' Fc = 1 N m."""
    if rig.effects.arm_coulomb is not None and rig.effects.arm_coulomb.Fc > 0:
        return rig.effects.arm_coulomb.Fc, "effects.arm_coulomb.Fc"
    if rig.compensation.coulomb.Fc > 0:
        return rig.compensation.coulomb.Fc, "compensation.coulomb.Fc"
    return DEFAULT_FC, "thesis section 4 (Fc = 1)"


def coulomb_effects(rig: RigConfig, fc: float) -> Effects:
    """The rig's own effects with the arm's Coulomb level set to ``fc`` (no stiction, no LuGre)."""
    data = rig.effects.present()
    data.pop("arm_lugre", None)
    data.pop("arm_stiction", None)
    data["arm_coulomb"] = {"Fc": fc}
    return Effects.model_validate(data)


def thesis_case(gains: np.ndarray) -> tuple[str, bool] | None:
    for name, (L, says) in SECTION4_CASES.items():
        if np.allclose(gains, L):
            return name, says
    return None


def describing_function_report(rig: RigConfig, gains: np.ndarray, fc: float) -> tuple[LimitCycleAnalysis, dict]:
    lc = analyze_limit_cycle(FurutaPlant(rig.lumped()), gains, fc, actuator=rig.actuator)
    out = lc.to_dict()
    out["sampled_loop_stable"] = analyze(rig, gains).stable
    case = thesis_case(gains)
    if case is not None:
        out["thesis_case"] = {"name": case[0], "thesis_says_limit_cycle": case[1]}
    if not out["sampled_loop_stable"]:
        out["notes"].append(
            "with the rig's θ filter, observer and command delay these gains do not stabilise the sampled loop "
            "(see `furuta-rt design --gains`); the analysis is of the ideal continuous loop"
        )
    return lc, out


def orbit_report(
    rig: RigConfig,
    gains: np.ndarray,
    fc: float,
    loop: str,
    lc: LimitCycleAnalysis | None = None,
    sim_duration: float = 40.0,
    transient: float = 15.0,
    keep: dict | None = None,
    step: Callable[[str], None] | None = None,
) -> dict:
    """Periodic orbit (shooting) vs long simulation of the same loop vs the describing function.
    ``keep``, if given, receives the PeriodicOrbit ("orbit") and the simulated Trajectory ("trajectory");
    ``step(label)``, if given, is told each stage as it starts (two: the orbit, the simulation)."""
    say = step or (lambda label: None)
    effects = coulomb_effects(rig, fc)

    def make() -> IdealLoop | SampledLoop:
        return IdealLoop(rig, gains, effects) if loop == "ideal" else SampledLoop(rig, gains, effects)

    try:
        say(f"periodic orbit of the {loop} loop (shooting)")
        orbit = find_periodic_orbit(make())
        say(f"{sim_duration:g} s simulation of the {loop} loop")
        sim, traj = simulate_limit_cycle(make(), duration=sim_duration, transient=transient,
                                         crossings_per_period=orbit.crossings_per_period)
    except OrbitNotFound as err:
        return {"loop": loop, "error": str(err)}
    if keep is not None:
        keep.update(orbit=orbit, trajectory=traj)
    worst = max(abs(v) for v in relative_errors(orbit.stats, sim).values())
    out: dict = {
        "loop": loop,
        "fc": fc,
        "orbit": orbit.to_dict(),
        "simulation": {"duration_s": sim_duration, "transient_s": transient, **sim.to_dict()},
        "orbit_vs_simulation": relative_errors(orbit.stats, sim),
    }
    df = lc.main if (loop == "ideal" and lc is not None) else None
    if loop == "sampled":
        preds = sampled_limit_cycle(rig, gains, fc)
        df = ([p for p in preds if p.stable] or preds or [None])[0]
    if df is not None and not df.stable:
        out["describing_function_note"] = (
            f"the describing-function solution ({df.omega:.3g} rad/s, φ̇ amplitude {df.amplitude_phidot:.3g} rad/s) is an "
            "unstable limit cycle, the threshold above which oscillations grow: not the orbit the loop settles on"
        )
    elif df is not None:
        o = orbit.stats
        out["describing_function"] = {"loop": loop, **df.to_dict()}
        out["describing_function_vs_orbit"] = {
            "period": (df.period - o.period) / o.period,
            "amplitude_phi_dot": (df.amplitude_phidot - o.amplitude["phi_dot"]) / o.amplitude["phi_dot"],
            "amplitude_phi": (df.amplitude_phi - o.amplitude["phi"]) / o.amplitude["phi"],
            "amplitude_theta": (df.amplitude_theta - o.amplitude["theta"]) / o.amplitude["theta"],
        }
    if worst > 0.05:
        out["simulation_note"] = (
            "the long simulation (from θ = 0.05 rad) did not settle on this orbit: it has another attractor, "
            "or the orbit's basin is smaller than that start"
        )
    peak = float(np.max(np.abs(orbit.trajectory.u)))
    if loop == "ideal" and peak > rig.actuator.limit:
        out["note"] = (f"the ideal loop commands up to {peak:.3g}, beyond the actuator limit "
                       f"{rig.actuator.limit:g} (not modelled in the ideal loop)")
    return out


def limit_cycle_report(
    rig: RigConfig,
    gains: list[float] | np.ndarray | None = None,
    fc: float | None = None,
    loops: tuple[str, ...] = (),
    step: Callable[[str], None] | None = None,
) -> dict:
    """Everything ``furuta-rt analyze limit-cycle`` prints, as one dict (``step``: see orbit_report;
    2 steps per loop)."""
    L = design_gains(rig) if gains is None else np.asarray(gains, dtype=float)
    fc_source = "--fc"
    if fc is None:
        fc, fc_source = default_fc(rig)
    lc, out = describing_function_report(rig, L, fc)
    out = {"rig": rig.name, "gains_source": "given" if gains is not None else rig.control.design,
           "fc_source": fc_source, **out}
    if loops:
        out["periodic_orbit"] = {loop: orbit_report(rig, L, fc, loop, lc, step=step) for loop in loops}
    return out
