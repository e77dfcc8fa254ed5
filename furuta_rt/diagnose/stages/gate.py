"""The prediction gate and the held-out fit metric: nothing that predicts worse is reported as found.

Windows (furuta_rt.diagnose.judgement.verify): the informative ones, spread over the whole recording, horizon from the
unstable pole of eq. 6. Blocked cross-validation: the windows, in time order, are dealt to N_FOLDS interleaved folds;
each fold's windows are predicted with the effects refitted (furuta_rt.diagnose.stages.findings.refit on an EquationModel with
a row filter) on the recording outside its windows and a margin around each, so no window is predicted with
parameters that saw it. The window stages' effects take their values from the stage's windows outside that span
(WindowFit.value_on); a free decay's from the whole decay (its fit is already leave-one-cycle-out).

The gate, on every found effect except the window stages' and the free decay's (those are chosen on their own
held-out windows — sticks, command peaks, cycles — and pass as they are, though they stay in the augmented model
that the metric judges; inverse-dynamics effects are refitted per fold, any other is taken at its value): an effect
is moved to ``not_predictive`` when the model without it (the others refitted) predicts the windows better by a
paired t ≥ T_HARM and by ≥ MIN_RISE relative, or diverges in at least MIN_EXTRA_DIVERGED fewer windows — evidence
of harm; no evidence keeps it (a small real effect such as a pendulum damping of 1e-4 N m s may change a 0.3 s
prediction by < 1 %). The worst one goes first, then the rest are judged again. When what is left still predicts
significantly worse than the nominal model, or diverges more, and removing all of it does better, all of it is moved.

Before that, the band test (``band_check``): every library effect enters eq. 4 through the same kernel on both sides,
so its fitted value does not depend on the kernel's width; an inverse-dynamics effect whose value, refitted with the
same set of effects in a band BAND_FACTOR times narrower (a kernel BAND_FACTOR times wider), moves by more than
BAND_SHARE of its size (its departure from the nominal model, or its value where that is smaller: a gain of 0.13
that becomes 0.24 has moved by a factor 2) and by more than BAND_Z combined standard errors is not that
effect — it stands in for dynamics outside eq. 4 (a compliance, a mode) whose effect on the residual depends on
frequency. It is moved out with that reason, the rest refitted and tested again. In an equation so shown to hold
dynamics outside eq. 4, the remaining inverse-dynamics effects must earn their place: each stays only if the model
with it predicts the held-out windows better than without it (paired t ≥ verify.T_DIFFERENT, or a prediction error
lower by MIN_PREDICTIVE_GAIN: a single step has too few windows for a t); an effect that other
dynamics can mimic (an input saturation clipping the fast peaks a compliance filters) would otherwise stay.

After the band test and before the gate, a θ offset below half the θ sensor's resolution (its count or its noise,
``theta_resolution``) is moved out: no sensor offset can be told from where the sensor's own zero falls (a swing-up
fitted 2e-5 rad, a fortieth of a count, to significance).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from furuta_rt.config import RigConfig
from furuta_rt.diagnose.judgement import verify
from furuta_rt.diagnose.judgement.verdict import above_floor, removes_excess
from furuta_rt.diagnose.regression.fitting import paired_t
from furuta_rt.diagnose.regression.library import CANDIDATES, Context, nominal_latency
from furuta_rt.diagnose.regression.selection import EquationModel, Evaluation, Spec
from furuta_rt.diagnose.regression.states import MAX_SIGMA
from furuta_rt.diagnose.stages import peaks, stickslip
from furuta_rt.diagnose.stages.findings import (
    LUGRE_CONTAINS,
    EquationResult,
    Found,
    Options,
    found_in,
    refit,
    within_bounds,
)
from furuta_rt.diagnose.stages.stickslip import WindowStage
from furuta_rt.model.effects import Effects

N_FOLDS = 4
T_HARM = 3.0  # paired t over windows: the model without the effect predicts better
MIN_RISE = 0.01  # ... and the effect raises the prediction error by at least this (relative)
MIN_EXTRA_DIVERGED = 2  # or the effect makes at least this many more windows diverge
ID = "inverse dynamics"
EXEMPT = ("stick windows", "peak windows", "free decay")  # sources judged on their own held-out windows
WINDOW_STAGES = ("stick windows", "peak windows")  # ... of which these must also predict in a suspect equation
BAND_FACTOR = 2.0  # the band test's kernel is this many times wider than the equation's
BAND_SHARE = 0.5  # an effect's value may move by less than this share of its departure from the nominal model ...
BAND_Z = 4.0  # ... or by less than this many combined standard errors
MIN_PREDICTIVE_GAIN = 0.05  # an effect that must earn its place stays when it lowers the prediction error this much
THETA_RESOLUTION_SHARE = 0.5  # a θ offset below this share of the θ sensor's resolution is not reported
EXPLAINS_ALONE = 0.5  # an effect removing this share of its equation's excess by itself is not suspected as a stand-in


@dataclass
class Plan:
    """The windows to predict, their folds and each fold's training rows."""

    starts: list[int]
    horizon: int
    fold_of: list[int]
    train: list[np.ndarray]  # per fold: the samples outside its windows' spans and margins
    spans: list[list[tuple[int, int]]]  # per fold: the [first, last) sample spans held out (one per window)
    candidates: int

    @property
    def folds(self) -> int:
        return len(self.train)

    def outside(self, fold: int, start: int, stop: int) -> bool:
        """Whether samples [start, stop] lie clear of every span the fold holds out."""
        return all(stop < lo or start > hi for lo, hi in self.spans[fold])


def make_plan(prep, rig: RigConfig, max_windows: int, horizon_s: float | None = None) -> Plan:
    """Informative windows (verify.informative_starts), dealt in time order to N_FOLDS interleaved folds: window i
    goes to fold i mod N_FOLDS, and a fold's training rows are the recording minus each of its windows with a margin
    (the kernel's reach). Interleaved rather than contiguous, so that every fold trains on every part of the
    recording: where the informative motion sits in one stretch (a swing-up before a long balance, one step from
    rest), a contiguous fold holding it would be predicted with parameters fitted only on the rest, where the
    effect is barely excited (a pendulum damping of 1.8e-5 can come out 6.6e-4 there)."""
    horizon = verify.horizon_ticks(rig, prep.dt) if horizon_s is None else max(5, round(horizon_s / prep.dt))
    starts, candidates = verify.informative_starts(prep, horizon, max_windows)
    folds = min(N_FOLDS, len(starts))
    margin = 2 * horizon + round(5 * MAX_SIGMA / prep.dt)  # the refit's filtered rows reach this far
    fold_of = [i % folds for i in range(len(starts))] if folds else []
    train = [np.ones(prep.n, dtype=bool) for _ in range(folds)]
    spans: list[list[tuple[int, int]]] = [[] for _ in range(folds)]
    for i, start in enumerate(starts):
        f = fold_of[i]
        lo, hi = max(0, start - margin), min(prep.n, start + horizon + 1 + margin)
        train[f][lo:hi] = False
        spans[f].append((lo, hi))
    return Plan(starts, horizon, fold_of, train, spans, candidates)


@dataclass
class Gated:
    """What the gate leaves: the found effects that predict, those moved out, and the final predictions."""

    found: list[Found]
    not_predictive: list[dict]
    plan: Plan
    nominal: verify.Prediction
    augmented: verify.Prediction
    fold_params: list[dict[str, dict[str, float]]] = field(default_factory=list)
    substep_hz: float = 2000.0


class Gate:
    """Predictions of the recording's windows for sets of found effects, refitted per fold."""

    def __init__(self, ctx: Context, ems: dict[str, EquationModel], opts: Options, plan: Plan,
                 stages: list[tuple[WindowStage, int]], notes: list[str]) -> None:
        self.ctx, self.ems, self.opts, self.plan, self.stages, self.notes = ctx, ems, opts, plan, stages, notes
        self._train: dict[tuple[str, int], EquationModel | None] = {}
        self._profiled: dict[tuple[str, int, str], Evaluation] = {}
        self._noted: set[str] = set()
        self.specs: dict[str, Spec] = {}  # each equation's current model (set by run, refitted when an effect goes)

    def train_model(self, eq: str, fold: int) -> EquationModel | None:
        """The equation's rows outside the fold (None: too few, the all-data fit is used)."""
        key = (eq, fold)
        if key not in self._train:
            em = EquationModel(self.ctx, eq, self.opts.thresholds, row_filter=self.plan.train[fold])
            ok = em.n_rows >= 20 * self.opts.thresholds.n_blocks
            if not ok and eq not in self._noted:
                self._noted.add(eq)
                self.notes.append(f"{eq} equation: too few rows outside some prediction folds; those windows use the "
                                  "all-data parameters")
            self._train[key] = em if ok else None
        return self._train[key]

    def fold_fit(self, eq: str, spec: Spec, fold: int) -> Evaluation:
        """``spec`` fitted on the rows outside the fold: the current model with its nonlinear parameters re-profiled
        (findings.refit), a model with effects left out of it by least squares at the current model's profiled values
        (the leave-one-out models of the gate cost one linear fit each)."""

        em = self.train_model(eq, fold) or self.ems[eq]
        full = self.specs.get(eq, spec)
        key = (eq, fold, repr(full))
        if key not in self._profiled:
            self._profiled[key] = refit(em, full)
        base = self._profiled[key]
        if spec == full:
            return base
        derived = base.spec
        for name in set(full.effects) - set(spec.effects):
            derived = derived.without(name)
        return em.evaluate(derived)

    def fold_params(self, found: list[Found], specs: dict[str, Spec], fold: int) -> dict[str, dict[str, float]]:
        """The found effects' parameters for predicting one fold's windows."""

        out: dict[str, dict[str, float]] = {}
        names = {f.name for f in found}
        for eq, spec in specs.items():
            if not spec.effects or not any(f.source == ID and f.equation == eq for f in found):
                continue
            ev = self.fold_fit(eq, spec, fold)
            for n in ev.spec.effects:
                if n in names and not (n in LUGRE_CONTAINS and "arm_lugre" in ev.spec.effects):
                    out[n] = within_bounds(n, ev.params[n])
        for stage, least in self.stages:
            outside = np.array([self.plan.outside(fold, w.start, w.start + w.horizon) for w in stage.windows])
            for name, fit in stage.fits.items():
                if name in names:
                    value = fit.value_on(outside) if outside.sum() >= least else fit.value
                    out[name] = {**stage.added[name], fit.param: value}
        for f in found:  # the rest (a free decay's, or a stage's without a per-window fit): as found
            out.setdefault(f.name, f.params)
        return out

    def predict(self, found: list[Found], specs: dict[str, Spec]) -> tuple[verify.Prediction, list[dict]]:
        """The windows predicted with ``found`` (inverse-dynamics ones refitted per fold from ``specs``)."""
        params = [self.fold_params(found, specs, f) if found else {} for f in range(self.plan.folds)]
        try:
            sets = [Effects.model_validate(p) for p in params]
        except ValueError:  # a combination the effects vocabulary forbids: not simulated
            sets = [Effects() for _ in params]
        p = self.plan
        return verify.predict(self.ctx.rig, sets, self.ctx.prep, self.ctx.fine, p.starts, p.horizon,
                              self.opts.substep_hz, p.fold_of), params


def harm(with_: verify.Prediction, without: verify.Prediction) -> tuple[bool, float]:
    """(evidence that what ``with_`` has and ``without`` lacks harms the prediction, paired t of with − without)."""
    t = paired_t(with_.per_window, without.per_window) if with_.windows > 1 else 0.0
    rise = (with_.nrmse - without.nrmse) / without.nrmse if without.nrmse > 0 else 0.0
    extra = int(with_.diverged.sum()) - int(without.diverged.sum())
    return (t >= T_HARM and rise >= MIN_RISE) or (extra >= MIN_EXTRA_DIVERGED and t > 0), t


def _numbers(w: verify.Prediction, wo: verify.Prediction, t: float) -> dict:
    return {"nrmse_with": w.nrmse, "nrmse_without": wo.nrmse, "paired_t": t, "windows": w.windows,
            "diverged_with": int(w.diverged.sum()), "diverged_without": int(wo.diverged.sum())}


def _reason(f: Found, w: verify.Prediction, wo: verify.Prediction, t: float) -> str:
    text = (f"lowers the inverse-dynamics residual by {100 * max(f.cv_gain, 0.0):.1f} % but the held-out prediction "
            f"error rises {wo.nrmse:.3f} → {w.nrmse:.3f} (paired t = {t:.1f} over {w.windows} windows)")
    dw, dwo = int(w.diverged.sum()), int(wo.diverged.sum())
    if dw > dwo:
        text += f"; the prediction diverges in {dw} windows with it, {dwo} without"
    return text


def _departure_origin(ctx: Context, name: str, param: str) -> float:
    """The value of an effect's main parameter in the nominal model (its departure is measured from it)."""
    match name:
        case "arm_inertia":
            return ctx.base_inertia
        case "input_gain":
            return ctx.known_gain
        case "command_latency":
            return nominal_latency(ctx.rig)
    return ctx.known_value(name, param)


def band_context(ctx: Context, factor: float = BAND_FACTOR) -> Context:
    """The recording's Context with each equation's kernel ``factor`` times wider (the fine kernel kept)."""
    def outer(eq: str) -> float:
        s = ctx.states(eq)
        return (s.outer or s.filt).sigma * factor
    return Context.build(ctx.prep, ctx.rig, outer("arm"), outer("pendulum"), ctx.fine.filt.sigma, ctx.also_search)


def band_check(ctx: Context, ems: dict[str, EquationModel], res: dict[str, EquationResult], names: list[tuple[str, str]],
               opts: Options, wide: Context | None = None) -> dict[str, dict]:
    """Per inverse-dynamics effect (``names``: (equation, effect)) whose value depends on the band (module
    docstring): its value in both bands, their standard errors and the kernel widths."""

    wide = wide or band_context(ctx)
    out: dict[str, dict] = {}
    for eq in dict.fromkeys(eq for eq, _ in names):
        ev = res[eq].selected
        em = EquationModel(wide, eq, opts.thresholds, row_filter=ems[eq].row_mask)
        if em.n_rows < 20 * opts.thresholds.n_blocks or not ev.spec.effects:
            continue
        other = refit(em, ev.spec)
        for e, name in names:
            if e != eq or name not in ev.params or name not in other.params:
                continue
            param = CANDIDATES[name].main
            if param not in ev.params[name] or param not in other.params[name]:
                continue
            v1, v2 = float(ev.params[name][param]), float(other.params[name][param])
            se1 = float(ev.se.get(name, {}).get(param, 0.0) or 0.0)
            se2 = float(other.se.get(name, {}).get(param, 0.0) or 0.0)
            size = min(abs(v1 - _departure_origin(ctx, name, param)), abs(v1))  # a gain of 0.1 moved to 0.2 moved
            moved = abs(v2 - v1)
            if moved > BAND_SHARE * size and moved > BAND_Z * float(np.hypot(se1, se2)):
                out[name] = {"equation": eq, "param": param, "value": v1, "value_wide": v2, "se": se1, "se_wide": se2,
                             "sigma": ctx.states(eq).filt.sigma, "sigma_wide": wide.states(eq).filt.sigma}
    return out


def _above_floor(ctx: Context, em: EquationModel, r: EquationResult, opts: Options) -> bool:
    ev = r.selected
    return above_floor(ctx, em, em.residual(ev.spec, ev.fit.coef), opts.seed)


def _explains_alone(ctx: Context, em: EquationModel, r: EquationResult, name: str, opts: Options) -> bool:
    """Whether the inverse-dynamics effect ``name`` by itself removes EXPLAINS_ALONE of its equation's excess over the
    noise floor (the selected model against it without ``name``, verdict.removes_excess): such an effect is what is
    missing, not a stand-in for it (a pendulum damping taking 2.6 % of the torque scale to 0.2 % on a swing-up where
    the floor is 0.1 %), and stays in a suspect equation without having to predict better."""
    ev = r.selected
    if name not in ev.spec.effects:
        return False
    y_nom = em.target(em.spec0())
    without = em.evaluate(ev.spec.without(name))
    share = (removes_excess(ctx, em, y_nom, em.residual(ev.spec, ev.fit.coef), opts.seed)
             - removes_excess(ctx, em, y_nom, em.residual(without.spec, without.fit.coef), opts.seed))
    return share >= EXPLAINS_ALONE


def theta_resolution(rig: RigConfig) -> float:
    """The θ sensor's resolution (rad): its count (ADC or encoder) or its noise, whichever is larger."""
    return max(float(rig.sensors.theta_rad_per_count), float(rig.sensors.theta_noise))


def _band_reason(b: dict) -> str:
    return (f"its {b['param']} depends on the frequency band: {b['value']:.4g} ± {b['se']:.2g} with the "
            f"{1000 * b['sigma']:.0f} ms kernel, {b['value_wide']:.4g} ± {b['se_wide']:.2g} with the "
            f"{1000 * b['sigma_wide']:.0f} ms one (a library effect's value does not; it stands in for dynamics "
            "outside eq. 4, such as a compliance or a mode)")


def run(ctx: Context, ems: dict[str, EquationModel], res: dict[str, EquationResult], found: list[Found],
        opts: Options, notes: list[str], stick: WindowStage | None = None, peak: WindowStage | None = None) -> Gated:
    """The prediction gate; ``res`` is updated in place (each equation refitted without the effects moved out)."""
    plan = make_plan(ctx.prep, ctx.rig, opts.max_windows, opts.horizon)
    stages = [(s, least) for s, least in ((stick, stickslip.MIN_WINDOWS), (peak, peaks.MIN_PEAK_WINDOWS))
              if s is not None and s.added]
    gate = Gate(ctx, ems, opts, plan, stages, notes)
    specs = {eq: r.selected.spec for eq, r in res.items()}
    gate.specs = specs
    found = list(found)
    moved: list[dict] = []

    def drop(gone: list[Found], reason: dict[str, str], numbers: dict[str, dict], key: str = "prediction") -> None:
        nonlocal found
        for eq in {f.equation for f in gone if f.source == ID}:
            spec = specs[eq]
            for f in gone:
                if f.equation == eq and f.source == ID:
                    spec = spec.without(f.name)
            r = res[eq]
            res[eq] = EquationResult(eq, r.rows, r.nominal, refit(ems[eq], spec) if spec.effects else r.nominal,
                                     r.trace, r.location)
            specs[eq] = res[eq].selected.spec
            names = {f.name for f in found if f.source == ID and f.equation == eq} - {f.name for f in gone}
            fresh = {f.name: f for f in found_in(ems[eq], res[eq], []) if f.name in names}
            found = [fresh.get(f.name, f) if f.source == ID and f.equation == eq else f for f in found]
        found = [f for f in found if f not in gone]
        moved.extend({"name": f.name, "equation": f.equation, "params": f.params, "reason": reason[f.name],
                      key: numbers[f.name]} for f in gone)

    wide = None
    for _ in range(3):  # the band test: effects whose value depends on the band go, the rest are tested again
        ids = [(f.equation, f.name) for f in found if f.source == ID]
        if not ids:
            break
        wide = wide or band_context(ctx)
        bad = band_check(ctx, ems, res, ids, opts, wide)
        if not bad:
            break
        gone = [f for f in found if f.source == ID and f.name in bad]
        drop(gone, {n: _band_reason(b) for n, b in bad.items()}, bad, key="band")
        notes.append("moved out (their value depends on the frequency band): " + ", ".join(f.name for f in gone))
    res_theta = theta_resolution(ctx.rig)
    small = [f for f in found if f.name == "theta_offset" and f.source == ID
             and abs(f.params["offset"]) < THETA_RESOLUTION_SHARE * res_theta]
    if small:  # below what the θ sensor resolves: indistinguishable from where the sensor's own zero falls
        drop(small, {f.name: (f"{f.params['offset']:.2g} rad is below half the θ sensor's resolution ({res_theta:.2g} rad: "
                              "its count or its noise): no sensor offset can be told from where its zero falls")
                     for f in small}, {f.name: {"offset": f.params["offset"], "resolution": res_theta} for f in small},
             key="resolution")
    nominal, _ = gate.predict([], specs)
    if not plan.starts:
        notes.append("the recording has no window to predict; the prediction gate and metric are skipped")
        return Gated(found, moved, plan, nominal, nominal, [], opts.substep_hz)
    current, params = gate.predict(found, specs) if found else (nominal, [])
    # an equation shown to hold dynamics outside eq. 4 (the band test), or whose residual stays above the noise floor
    # with its effects (verdict.above_floor): its effects may stand in for what is missing, and must predict better —
    # except one that by itself removes most of the excess (_explains_alone)
    suspect = [eq for eq in specs if any(m["equation"] == eq for m in moved) or (
        any(f.equation == eq and f.source == ID for f in found) and _above_floor(ctx, ems[eq], res[eq], opts))]
    for eq in suspect:  # the window stages' effects too: sticks held at a count by a dry friction of 1e-5 N m can
        # stand in for a model that creeps (a pendulum-length error), and are no evidence once the equation is suspect
        for f in [f for f in found if f.equation == eq and f.source in (ID, *WINDOW_STAGES)]:
            if f.source == ID and _explains_alone(ctx, ems[eq], res[eq], f.name, opts):
                continue
            rest = [g for g in found if g is not f]
            without, _ = gate.predict(rest, {**specs, eq: specs[eq].without(f.name)} if f.source == ID else specs)
            t = paired_t(without.per_window, current.per_window) if current.windows > 1 else 0.0
            gain = (without.nrmse - current.nrmse) / without.nrmse if without.nrmse > 0 else 0.0
            if t < verify.T_DIFFERENT and gain < MIN_PREDICTIVE_GAIN:  # few windows: a large gain is evidence too
                what = ("the {eq} equation's fitted dynamics depend on the frequency band (dynamics outside eq. 4)"
                        if any(m["equation"] == eq for m in moved) else
                        "the {eq} equation's residual stays above its noise floor with its effects (physics is missing)")
                why = (f"{what.format(eq=eq)}, and this effect does not improve the held-out prediction "
                       f"({without.nrmse:.4f} without it, {current.nrmse:.4f} with it, paired t = {t:.1f} < "
                       f"{verify.T_DIFFERENT:g}): it may stand in for what is missing")
                drop([f], {f.name: why}, {f.name: _numbers(current, without, -t)})
                current, params = gate.predict(found, specs) if found else (nominal, [])

    while True:  # the most harmful effect first, then the rest again
        worst = None
        for f in [f for f in found if f.source not in EXEMPT]:
            rest = [g for g in found if g is not f]
            s = {**specs, f.equation: specs[f.equation].without(f.name)} if f.source == ID else specs
            without, _ = gate.predict(rest, s)
            bad, t = harm(current, without)
            if bad and (worst is None or t > worst[1]):
                worst = (f, t, without)
        if worst is None:
            break
        f, t, without = worst
        drop([f], {f.name: _reason(f, current, without, t)}, {f.name: _numbers(current, without, t)})
        current, params = gate.predict(found, specs) if found else (nominal, [])
    ids = [f for f in found if f.source not in EXEMPT]
    if ids and verify.compare(nominal, current)["verdict"] in ("worse", "diverges"):
        rest = [f for f in found if f.source in EXEMPT]
        without, _ = gate.predict(rest, specs) if rest else (nominal, [])
        bad, t = harm(current, without)
        if bad:
            why = (f"together with the other gated effects it predicts the held-out windows worse than the "
                   f"nominal model ({nominal.nrmse:.3f} → {current.nrmse:.3f}); without them {without.nrmse:.3f} "
                   f"(paired t = {t:.1f} over {current.windows} windows)")
            drop(ids, {f.name: why for f in ids}, {f.name: _numbers(current, without, t) for f in ids})
            current, params = gate.predict(found, specs) if found else (nominal, [])
    return Gated(found, moved, plan, nominal, current, params, opts.substep_hz)
