"""The findings of a diagnosis and the operations on them: what an equation's regression selected (EquationResult),
the effects found (Found), each equation's model refitted (refit) and its effects read from it (found_in), within the
effects vocabulary's bounds (within_bounds). Shared by the pipeline (furuta_rt.diagnose.engine) and its stages."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from furuta_rt.diagnose.judgement.locate import Location
from furuta_rt.diagnose.regression.library import CANDIDATES
from furuta_rt.diagnose.regression.selection import EquationModel, Evaluation, Spec, Thresholds
from furuta_rt.model.effects import EFFECT_TYPES, Effects


@dataclass(frozen=True)
class Options:
    sigma_arm: float | None = None  # s, Gaussian width for the arm equation (None: the encoder decides)
    sigma_pend: float = 0.05  # s, for the pendulum equation (its noise is the encoder's, through γ·φ̈)
    sigma_fine: float = 0.005  # s, for nonlinear regressors (signs) and initial states
    thresholds: Thresholds = field(default_factory=Thresholds)
    horizon: float | None = None  # s, prediction window (None: from the unstable pole of eq. 6, verify.horizon_ticks)
    max_windows: int = 40
    closed_loop: bool = True
    stick_windows: bool = True  # the stick–slip stage (breakaway torque, actuator timing from the sticks)
    substep_hz: float = 2000.0  # physics substeps of the verification simulations
    ambiguity_t: float = 3.0  # paired t on the blocks above which two look-alikes are told apart ...
    ambiguity_gain: float = 0.01  # ... when one also fits better by at least this (relative held-out error)
    seed: int = 0
    check_conventions: bool = True  # refuse a recording whose signs or angle units are clearly not the rig's
    also_search: tuple[str, ...] = ()  # registered effects outside the default search to try too (e.g. arm_air_drag)


@dataclass
class Found:
    name: str
    equation: str
    params: dict[str, float]
    se: dict[str, float]
    t: float
    cv_gain: float  # held-out error reduction this effect brings (relative, given the others)
    source: str = "inverse dynamics"  # or "free decay" (energy lost per swing)
    pinned: bool = True  # the data pins this parameter alone (identify.pinning), not only a combination of it
    combinations: list[dict] = field(default_factory=list)  # the pinned combinations it enters, when it is not pinned

    def as_json(self) -> dict:
        return {"name": self.name, "params": self.params}


@dataclass
class EquationResult:
    equation: str
    rows: int
    nominal: Evaluation
    selected: Evaluation
    trace: list[dict]
    location: Location

    @property
    def gain(self) -> float:
        return (self.nominal.cv - self.selected.cv) / self.nominal.cv if self.nominal.cv else 0.0


def effects_of(found: list[Found]) -> Effects:
    return Effects.model_validate({f.name: f.params for f in found})


def refit(em: EquationModel, spec: Spec) -> Evaluation:
    """The effects of ``spec`` fitted on ``em``'s rows: each nonlinear parameter re-profiled with the others
    at their current values (one pass of coordinate descent), then the linear ones by least squares."""
    nl_t: dict[str, float] = {}
    nl_se: dict[str, dict[str, float]] = {}
    for name in spec.effects:
        if CANDIDATES[name].nonlinear:
            ev = em.evaluate_with(spec.without(name), name)
            spec = ev.spec
            nl_t[name] = ev.t_stat[name]
            nl_se[name] = ev.se[name]
    final = em.evaluate(spec)
    final.t_stat.update(nl_t)
    final.se.update(nl_se)
    return final


def found_in(em: EquationModel, r: EquationResult, notes: list[str]) -> list[Found]:
    """The selected effects of one equation, each with the held-out gain it brings given the others."""
    out = []
    ev = r.selected
    for name in ev.spec.effects:
        if name in LUGRE_CONTAINS and "arm_lugre" in ev.spec.effects:
            continue  # arm_lugre carries the Coulomb level and the viscous term
        kind = CANDIDATES[name].nonlinear
        if kind is not None:
            grid = em.grid(kind)
            value = {"inertia": ev.spec.d_inertia, "vs": ev.spec.vs}.get(kind, getattr(ev.spec.path, kind, None))
            step = float(np.median(np.diff(grid)))
            if value is not None and (value <= grid[0] + step or value >= grid[-1] - step):
                notes.append(f"{name}: {ev.params[name]} is at the edge of the range searched; the data asks for "
                             "more than the library's range (treat it as a sign of other missing physics)")
        without = em.evaluate(ev.spec.without(name))
        gain = (without.cv - ev.cv) / without.cv if without.cv else 0.0
        params = within_bounds(name, ev.params[name])
        out.append(Found(name, r.equation, params, ev.se.get(name, {}), float(ev.t_stat.get(name, 0.0)), gain))
    return out


LUGRE_CONTAINS = ("arm_coulomb", "arm_viscous")


def within_bounds(name: str, params: dict[str, float]) -> dict[str, float]:
    """Totals put back inside the vocabulary's bounds (≥ 0 where it says so): with the rig's own effect in the nominal
    model, "the data has none of it" is a departure of −value, whose fit scatters around 0 either side."""
    out = dict(params)
    for key, info in EFFECT_TYPES[name].model_fields.items():
        if key in out and any(getattr(m, "ge", None) == 0 for m in info.metadata):
            out[key] = max(out[key], 0.0)
    if name == "arm_spring" and out["k"] == 0.0:
        out["phi0"] = 0.0  # no spring: its rest angle means nothing
    return out
