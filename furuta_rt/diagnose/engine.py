"""`diagnose`: locate the mismatch between eq. 4 and a recording, name the missing physics, fit it, and
show the fit improve.

Pipeline (every physical model from furuta_rt.model / furuta_rt.sim):

1. states (regression/states.py) — the recording on a grid, θ reconstructed through the inverse Bessel path, everything
   (states, accelerations, the held command) seen through one Gaussian kernel;
2. selection (regression/selection.py) — per equation of eq. 4 (arm, pendulum), forward selection of named effects on held-out
   time blocks, with significance and admissibility checks (furuta_rt.diagnose.regression.selection);
3. refit — the nonlinear parameters (delay, deadzone, saturation, ΔJ) re-profiled jointly with the others;
4. window stages — where the arm sticks, its breakaways (stiction, LuGre, actuator timing:
   furuta_rt.diagnose.stages.stickslip); where the largest commands are out of the regression's reach, the arm's
   response to them (a torque limit: furuta_rt.diagnose.stages.peaks), simulated with the shared Simulator;
5. look-alikes — each selected effect against its look-alike: if the data cannot tell them apart,
   both are reported with the experiment that would (gain ↔ inertia decided by the κ test when it can);
6. prediction gate and metric (furuta_rt.diagnose.stages.gate) — multi-step prediction of informative windows
   spread over the recording, each with parameters refitted away from it (blocked cross-validation); an
   effect whose presence makes that prediction significantly worse is moved to ``not_predictive``;
   the augmented model against the nominal one by a paired test over windows (improved / unchanged /
   worse / diverges); closed-loop re-simulation statistics.

The rig's own [effects] are part of the nominal model; what is found is reported as corrected totals.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from furuta_rt.config import RigConfig
from furuta_rt.diagnose.judgement import noise, practical, verdict, verify
from furuta_rt.diagnose.judgement.locate import describe, locate
from furuta_rt.diagnose.regression import identify
from furuta_rt.diagnose.regression.fitting import Stats, fit, paired_t
from furuta_rt.diagnose.regression.library import ARM, CANDIDATES, PEND, STICTION_STILL_TICKS, STILL_TICKS, Context
from furuta_rt.diagnose.regression.selection import JOINT, EquationModel, Evaluation
from furuta_rt.diagnose.regression.states import GaussianFilter, Prepared, prepare
from furuta_rt.diagnose.stages import armlock, conventions, gate, latency, onset, peaks, stickslip, swing
from furuta_rt.diagnose.stages.decay import DecayFit, DecayResult, free_decay
from furuta_rt.diagnose.stages.findings import (
    LUGRE_CONTAINS,
    EquationResult,
    Found,
    Options,
    effects_of,
    found_in,
    refit,
)
from furuta_rt.diagnose.stages.rest import bias_at_rest as rest_test
from furuta_rt.model.effects import Effects
from furuta_rt.recording import Recording

EXPERIMENTS: dict[frozenset[str], str] = {
    frozenset({"arm_coulomb", "input_deadzone"}): (
        "a slow constant-velocity arm sweep (Coulomb friction needs the torque Fc at any speed, a deadzone lets "
        "the arm coast with |u| below the width) or a dither on u (it smooths a deadzone, not friction)"
    ),
    frozenset({"input_gain", "arm_inertia"}): (
        "a static torque test (a known command with the arm held against a force gauge measures the gain alone) "
        "or a repeat with a known inertia added to the arm"
    ),
    frozenset({"input_gain", "arm_bias"}): (
        "a command that changes while the arm moves (several step levels, a sine) or a rest at zero command: on one "
        "constant step the gain's extra torque and a constant one are the same column; at rest a bias moves the arm"
    ),
    frozenset({"arm_viscous", "arm_coulomb"}): (
        "runs at several arm speeds in both directions (viscous friction grows with the speed, Coulomb friction does "
        "not; on one speed in one direction the two are the same constant torque)"
    ),
    frozenset({"pendulum_viscous", "pendulum_coulomb"}): (
        "a pendulum free decay from a large angle (viscous damping: exponential envelope; Coulomb: linear)"
    ),
    frozenset({"arm_spring", "arm_inertia"}): (
        "an arm excitation with more than one frequency (a chirp, steps, or a second sine): a spring's torque follows "
        "φ − φ0 and an inertia's φ̈, which on a single frequency are the same column (k = −ΔJ·ω²)"
    ),
    frozenset({"theta_offset", "arm_spring"}): (
        "a pendulum free decay (it comes to rest hanging at θ = π + offset: a sensor offset shows there, a cable "
        "spring does not) and a slow arm sweep (a spring needs the torque k(φ − φ0))"
    ),
}


@dataclass
class Diagnosis:
    effects: list[Found]
    fit: dict
    located: str
    ambiguities: list[dict]
    lookalikes: list[dict]
    equations: dict[str, EquationResult]
    closed_loop: dict | None
    notes: list[str]
    seconds: float
    rig: str
    context: Context = field(repr=False)
    models: dict[str, EquationModel] = field(default_factory=dict, repr=False)
    decay: dict | None = None  # the free-decay analysis, when the recording is one
    decay_result: DecayResult | None = field(default=None, repr=False)
    prediction: dict = field(default_factory=dict, repr=False)  # starts, horizon, train effects (for figures)
    stick: stickslip.WindowStage | None = field(default=None, repr=False)  # the stick–slip windows, when there are sticks
    peak: stickslip.WindowStage | None = field(default=None, repr=False)  # the command-peak windows, when they ran
    starts: onset.OnsetTiming | None = field(default=None, repr=False)  # the arm's starts from rest, when they timed it
    not_predictive: list[dict] = field(default_factory=list)  # effects the prediction gate moved out (gate.run)
    verdicts: dict[str, verdict.EquationVerdict] = field(default_factory=dict, repr=False)  # per equation
    summary: str = ""  # one line: the verdicts (furuta_rt.diagnose.judgement.verdict)
    identification: dict | None = None  # the arm's jointly calibrated parameters and identifiable combinations
    below_practical: list[dict] = field(default_factory=list)  # effects too small to matter (judgement.practical)
    arm_lock: dict | None = None  # the arm's rests against a torque: dry friction or a dead band (stages.armlock)

    @property
    def names(self) -> list[str]:
        return [e.name for e in self.effects]

    def found_effects(self) -> Effects:
        return effects_of(self.effects)

    def to_json(self) -> dict:
        """One JSON-ready object (non-finite numbers become null)."""
        return plain(self._json())

    def _json(self) -> dict:
        return {
            "summary": self.summary,
            "effects": [e.as_json() for e in self.effects],
            "fit": {k: self.fit[k] for k in FIT_KEYS},
            "not_predictive": self.not_predictive,
            "below_practical_size": self.below_practical,
            "located": self.located,
            "ambiguities": self.ambiguities,
            "lookalikes": self.lookalikes,
            "identification": self.identification,
            "evidence": [
                {"name": e.name, "equation": e.equation, "source": e.source, "cv_gain": e.cv_gain, "t": e.t, "se": e.se,
                 "pinned": e.pinned, "pinned_combinations": e.combinations}
                for e in self.effects
            ],
            "free_decay": self.decay,
            "arm_rests": self.arm_lock,
            "stick_windows": self.stick.as_json() if self.stick is not None else None,
            "peak_windows": self.peak.as_json() if self.peak is not None else None,
            "arm_starts": self.starts.as_json() if self.starts is not None else None,
            "fit_details": {k: v for k, v in self.fit.items() if k not in FIT_KEYS},
            "closed_loop": self.closed_loop,
            "equations": {
                eq: {
                    "rows": r.rows, "nominal_rms": r.nominal.fit.cv_rms, "augmented_rms": r.selected.fit.cv_rms,
                    "cv_gain": r.gain, "relative_residual": r.location.relative_rms,
                    "correlations": r.location.correlations, "regions": r.location.regions,
                    **(self.verdicts[eq].as_json() if eq in self.verdicts else {}),
                }
                for eq, r in self.equations.items()
            },
            "notes": self.notes,
            "rig": self.rig,
            "seconds": self.seconds,
        }


FIT_KEYS = ("metric", "nominal", "augmented", "verdict", "paired_t", "paired_t_log", "nominal_diverged",
            "augmented_diverged", "windows", "window_times_s", "horizon_s")


def plain(x: object) -> object:
    """Python floats/ints/lists/dicts only, with NaN and ±inf as None (strict JSON)."""
    if isinstance(x, dict):
        return {str(k): plain(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [plain(v) for v in x]
    if isinstance(x, bool | str) or x is None:
        return x
    if isinstance(x, int | np.integer):
        return int(x)
    if isinstance(x, float | np.floating):
        return float(x) if np.isfinite(x) else None
    return x


# ------------------------------------------------------------------------------------ stages
def check_lookalikes(
    ems: dict[str, EquationModel], res: dict[str, EquationResult], opts: Options
) -> tuple[list[dict], list[dict], dict[str, Evaluation]]:
    """(ambiguities, look-alikes told apart, equations whose look-alike alternative the data favours) for the
    selected effects."""
    ambiguous: list[dict] = []
    apart: list[dict] = []
    swaps: dict[str, Evaluation] = {}
    selected = {n: eq for eq, r in res.items() for n in r.selected.spec.effects}
    bases: dict[str, Evaluation] = {}
    for name, eq in selected.items():
        r = res[eq]
        for other in dict.fromkeys((*CANDIDATES[name].lookalikes, *ems[eq].rivals(name, r.selected.spec))):
            pair = frozenset({name, other})
            if other in selected or any(set(a["effects"]) == pair for a in ambiguous + apart):
                continue
            experiment = EXPERIMENTS.get(pair, "")
            other_eq = CANDIDATES[other].equation
            if other_eq != eq:  # the two act in different equations of eq. 4
                em_o, sel_o = ems[other_eq], res[other_eq].selected
                if em_o.n_rows < 20 * opts.thresholds.n_blocks or not sel_o.cv:
                    why = f"{other} would act in the {other_eq} equation, which has too few usable samples to test it"
                else:
                    gain_o = (sel_o.cv - em_o.evaluate_with(sel_o.spec, other).cv) / sel_o.cv
                    why = f"{other} would act in the {other_eq} equation and improves it by {100 * max(gain_o, 0):.2f} % only"
                apart.append({
                    "effects": [name, other], "reported": name,
                    "reason": f"{name} acts in the {eq} equation, where the mismatch is; {why}",
                    "experiment": experiment,
                })
                continue
            alt = ems[eq].evaluate_with(r.selected.spec.without(name), other)
            base = bases.get(name) or bases.setdefault(name, fair_baseline(ems[eq], r.selected, name))
            t = paired_t(alt.fit.cv_block, base.fit.cv_block)
            plausible = CANDIDATES[other].plausible(alt.params[other], ems[eq].ctx.rig, ems[eq].ctx.arm_travel)
            rel = (alt.cv - base.cv) / base.cv
            # told apart: the alternative is clearly worse (by ≥ 1 % and consistently over the blocks, or by ≥ 10 %)
            apart_by_data = _clearly_worse(rel, t, opts)
            significant = alt.t_stat.get(other, 0.0) >= opts.thresholds.t_min
            rest = rest_test(ems[eq].ctx, r.selected if name == "arm_bias" else alt) if "arm_bias" in pair else None
            if rest is not None and rest["contradicts"] and (name != "arm_bias" or (plausible and significant)):
                keep, drop = (other, name) if name == "arm_bias" else (name, other)
                if keep == other and eq in swaps:
                    continue  # the library's own look-alike (tried first) already takes the bias's place
                if keep == other:
                    swaps[eq] = alt
                apart.append({"effects": [keep, drop], "reported": keep, "rest": rest, "experiment": experiment,
                              "reason": f"{keep} rather than arm_bias: {rest['text']}"})
                continue
            sep = None
            if pair == frozenset({"input_gain", "arm_inertia"}) and plausible and significant:
                sep_gain = (r.selected.params if name == "input_gain" else alt.params)["input_gain"]["gain"]
                sep = gain_inertia_separation(ems[eq], r.selected, sep_gain, name == "input_gain")
            if sep is not None and sep["verdict"] in ("selected", "alternative"):
                keep, drop = (name, other) if sep["verdict"] == "selected" else (other, name)
                if keep == other:
                    swaps[eq] = alt
                apart.append({"effects": [keep, drop], "reported": keep, "separation": sep, "experiment": experiment,
                              "reason": f"{keep} rather than {drop}: {sep['text']}"})
            elif plausible and significant and not apart_by_data:
                named, rival, rival_model = name, other, alt.params
                # a tie of the library's look-alikes that the alternative edges (by < 1 %) is named; and a datasheet
                # parameter of the model (select.JOINT) in place of an effect the model does not have, whenever it
                # scores better (the parameter is the simpler account: a spring on a one-frequency sine is an inertia)
                prefer = other in JOINT and name not in JOINT
                if (rel < 0 if prefer else -opts.ambiguity_gain < rel < 0) and other in CANDIDATES[name].lookalikes \
                        and eq not in swaps:
                    swaps[eq] = alt
                    named, rival, rival_model, rel, t = other, name, base.params, -rel / (1 + rel), -t
                    if sep is not None:  # the κ test read from the model now named
                        sep = gain_inertia_separation(ems[eq], alt, sep_gain, other == "input_gain")
                    if _clearly_worse(rel, t, opts):  # the effect first selected, against the parameter now named
                        apart.append({"effects": [named, rival], "reported": named, "experiment": experiment,
                                      "reason": f"{rival} in its place fits worse ({100 * rel:+.2f} % held-out error, "
                                                f"paired t = {t:.1f})"})
                        continue
                entry = {
                    "effects": [named, rival], "reported": named,
                    "alternative": {"name": rival, "params": rival_model[rival]},
                    "alternative_model": rival_model,  # the whole equation's effects under the alternative
                    "cv_difference": rel, "paired_t": t,
                    "reason": f"the data fits {rival} almost as well ({100 * rel:+.2f} % held-out error, paired t = {t:.1f})",
                    "experiment": experiment,
                }
                if sep is not None:
                    entry["separation"] = sep
                    entry["reason"] += f"; {sep['text']}: too close to tell"
                ambiguous.append(entry)
            else:
                if not plausible:
                    why = f"{other} in its place needs implausible values {alt.params[other]}"
                elif not significant:
                    why = f"{other} in its place is not significant (t = {alt.t_stat.get(other, 0.0):.1f})"
                else:
                    why = f"{other} in its place fits worse ({100 * rel:+.2f} % held-out error, paired t = {t:.1f})"
                apart.append({"effects": [name, other], "reported": name, "reason": why, "experiment": experiment})
    return ambiguous, apart, swaps


def _clearly_worse(rel: float, t: float, opts: Options) -> bool:
    """Whether a look-alike's held-out error ``rel`` (relative, against the model named) and paired t tell it apart:
    worse by ≥ ambiguity_gain and consistently over the blocks, or by ≥ 10 × ambiguity_gain."""
    return rel >= opts.ambiguity_gain and (t >= opts.ambiguity_t or rel >= 10 * opts.ambiguity_gain)


def fair_baseline(em: EquationModel, selected: Evaluation, name: str) -> Evaluation:
    """The selected model scored as its look-alike alternative is: ``name``'s nonlinear parameter (ΔJ, a delay, a
    width) re-profiled inside each held-out fold, as ``evaluate_with`` does for the alternative. The refitted
    selection holds that parameter at its full-data optimum, so its held-out error is optimistic next to a profiled
    alternative's (on a gain ↔ inertia tie that bias alone read as paired t = 3.4 for the inertia)."""
    if not CANDIDATES[name].nonlinear:
        return selected
    return em.evaluate_with(selected.spec.without(name), name)


def gain_inertia_separation(em: EquationModel, selected: Evaluation, gain: float, gain_model: bool) -> dict:
    """Whether the arm equation tells an input gain g from an arm-inertia change, and which one it favours.

    Divided by g, the gain model reads u = (M22/g) φ̈ + (P + F)/g with P = ID_arm at φ̈ = 0 (the pendulum's
    reaction γ cos θ θ̈ and the velocity terms of eq. 4) and F the friction (refitted either way); the inertia
    model reads u = (M22 + ΔJ) φ̈ + P + F. Only P's coefficient differs (1/g against 1). Neither effect enters
    the pendulum equation (no u, no J there), so that equation cannot help. The test: the coefficient κ of an
    extra column P in the selected model (``gain`` is the gain of whichever model has one; ``gain_model``: the
    selected one does) is 0 if the selected model is right and 1 − g (selected gain) or 1 − 1/g (selected
    inertia) if the other one is; κ's standard error (blocked jackknife) says which, if either, the data rejects.
    """
    ctx = em.ctx
    X, _ = em.design(selected.spec)
    P = ctx.arm_pendulum_part
    y, Xp = em.target(selected.spec), np.column_stack([X, P])
    if selected.spec.d_inertia:
        w = ctx.arm_weight(selected.spec.d_inertia)
        y, Xp = y * w, Xp * np.asarray(w)[:, None]
    f = fit(Stats.of(y, Xp, em.blocks))
    kappa, se = float(f.coef[-1]), max(float(f.se[-1]), 1e-12)
    g = gain / ctx.known_gain  # the departure from the nominal model's gain
    other = 1.0 - g if gain_model else 1.0 - 1.0 / g  # κ if the alternative is the truth
    z_sel, z_alt = abs(kappa) / se, abs(kappa - other) / se
    resolved = abs(other) >= SEPARATION_Z * se
    verdict = ("selected" if z_alt >= SEPARATION_Z and z_sel < CONSISTENT_Z else
               "alternative" if z_sel >= SEPARATION_Z and z_alt < CONSISTENT_Z else "neither") if resolved else "unresolved"
    rows = em.row_mask
    share = float(np.sqrt(np.mean(P[rows] ** 2)) / (np.sqrt(np.mean(ctx.command_torque(selected.spec.path)[rows] ** 2)) or 1.0))
    text = (f"the term that tells them apart, the pendulum's reaction on the arm (rms {100 * share:.2f} % of the arm torque "
            f"here; an input gain scales it, an inertia change does not), has coefficient κ = {kappa:+.3f} ± {se:.3f}; the "
            f"reported model predicts 0, the alternative {other:+.3f}")
    return {"kappa": kappa, "se": se, "predicted_alternative": other, "pendulum_share": share, "verdict": verdict,
            "text": text}


SEPARATION_Z = 4.0  # the two predictions of κ must be this many standard errors apart, and the rejected one this far off
CONSISTENT_Z = 2.0  # ... and the favoured one within this many


def balancing_span(rec: Recording, notes: list[str]) -> Recording:
    """A log's longest stretch of balancing ticks (idle or tripped ticks follow other physics: the loop is
    open, the pendulum may hang or be held); the whole recording when it has no such column."""
    flag = rec.extra.get("balancing")
    if flag is None or bool(np.all(flag > 0.5)) or not bool(np.any(flag > 0.5)):
        return rec
    on = np.concatenate([[0], (flag > 0.5).astype(int), [0]])
    starts, stops = np.flatnonzero(np.diff(on) == 1), np.flatnonzero(np.diff(on) == -1)
    i = int(np.argmax(stops - starts))
    a, b = int(starts[i]), int(stops[i])
    notes.append(f"diagnosed the longest balancing stretch of the log, t = {rec.t[a]:.1f}–{rec.t[b - 1]:.1f} s")
    out = rec.slice(a, b)
    out.meta["stretch_of_log"] = True
    return out


def moving_start(rec: Recording) -> str:
    """Why a stretch cut out of a log does not start as a run does (at rest near upright with the arm near its zero),
    or '' when it does: a balancing stretch after a swing-up's catch starts with the pendulum and the arm moving and
    the arm turns away from zero, which a closed-loop re-simulation from rest (verify.resimulate) cannot reproduce."""
    k = min(len(rec) - 1, 10)
    if k < 2:
        return ""
    span = float(rec.t[k] - rec.t[0])
    phi_dot = abs(float(rec.phi[k] - rec.phi[0])) / span
    theta_dot = abs(float(rec.theta[k] - rec.theta[0])) / span
    if phi_dot > START_REST or theta_dot > START_REST or abs(float(rec.phi[0])) > START_PHI:
        return (f"the balancing stretch starts moving (φ = {float(rec.phi[0]):+.2f} rad, |φ̇| ≈ {phi_dot:.2f} rad/s, "
                f"|θ̇| ≈ {theta_dot:.2f} rad/s: after a swing-up's catch)")
    return ""


START_REST = 0.5  # rad/s: a stretch starting faster than this is not at rest
START_PHI = 1.0  # rad: ... or with the arm this far from its zero


ARM_SIGMAS = (0.03, 0.04, 0.05)
MAX_QUANTISATION_RATIO = 0.02


def arm_sigma(prep: Prepared) -> float:
    """The narrowest kernel that holds the encoder's quantisation noise in φ̈ below 2 % of the φ̈ signal.

    The arm residual's noise is that quantisation error times the inertia; it also leaks into the command
    (u feeds back φ), so where it is large it biases the input-side parameters (delay, gain). Wider
    kernels cut it as σ^−2.5 but blur the reversals, so the narrowest adequate one is used."""
    for sigma in ARM_SIGMAS:
        f = GaussianFilter.build(sigma, prep.dt)
        noise = prep.phi_lsb / np.sqrt(12.0) * float(np.linalg.norm(f.kernels[2]))
        signal = float(np.std(f.apply(prep.phi, 2)[prep.valid]))
        if signal > 0 and noise / signal <= MAX_QUANTISATION_RATIO:
            return sigma
    return ARM_SIGMAS[-1]


def diagnose(rec: Recording, rig: RigConfig, options: Options | None = None) -> Diagnosis:
    """Diagnose ``rec`` against ``rig`` (see the module docstring)."""
    opts = options or Options()
    t0 = time.perf_counter()
    notes: list[str] = list(rec.meta.get("input_notes", []))  # what the reader converted (diagnose.sanity)
    rec = balancing_span(rec, notes)
    prep = prepare(rec, rig)
    notes += prep.notes + (conventions.conventions(prep, rig) if opts.check_conventions else [])
    sigma_arm = opts.sigma_arm or arm_sigma(prep)
    ctx = Context.build(prep, rig, sigma_arm, opts.sigma_pend, opts.sigma_fine)
    if noise.sensor_noise(ctx).note:
        notes.append(noise.sensor_noise(ctx).note)
    ems: dict[str, EquationModel] = {}
    res: dict[str, EquationResult] = {}
    for eq in (ARM, PEND):
        ems[eq], res[eq] = _select(ctx, eq, opts)
        if ems[eq].n_rows < 20 * opts.thresholds.n_blocks:
            notes.append(
                f"{eq} equation: only {ems[eq].n_rows} usable samples "
                + ("(the arm hardly moves: arm-side effects cannot be assessed; excite the arm, e.g. an arm reference)"
                   if eq == ARM else "")
            )
    found = [f for eq in res for f in found_in(ems[eq], res[eq], notes)]
    stick = _stick_windows(ctx, found, ems, res, opts, lugre=False) if opts.stick_windows else None
    found = _retimed(stick, found, ems, res)
    if stick is not None and {"arm_stiction", "arm_lugre"} & set(stick.added):
        # with a breakaway torque above the sliding level the arm may also stick briefly at reversals, where its
        # friction is the held torque, not ±Fc: the arm regression is redone without any short stay at one count
        # (and the stick windows are read again on top of the sliding level found there)
        em, r = _select(ctx, ARM, opts, ctx.clear_of(ctx.stays(STICTION_STILL_TICKS)))
        if "arm_coulomb" in r.selected.spec.effects and em.n_rows >= max(RESELECT_MIN_ROWS, RESELECT_MIN_SHARE * ems[ARM].n_rows):
            ems[ARM], res[ARM] = em, r
            found = [f for eq in res for f in found_in(ems[eq], res[eq], [])]
            notes.append(f"arm equation: with a breakaway above the sliding level, stays of ≥ {STICTION_STILL_TICKS} ticks at "
                         f"one encoder count are left out too (they may be short sticks); {em.n_rows} rows")
        else:  # the regression's effects as they were (a delay the windows re-timed among them)
            found = [f for eq in res for f in found_in(ems[eq], res[eq], [])]
        first, stick = stick, _stick_windows(ctx, found, ems, res, opts, only=set(stick.added))
        found = _retimed(stick, found, ems, res)
        if stick is not None:  # what the first reading compared stays on record
            stick.tried = [{**t, "pass": 1} for t in first.tried] + [{**t, "pass": 2} for t in stick.tried]
            stick.lookalikes += [a for a in first.lookalikes if a["effects"][1] not in stick.added]
            stick.ambiguities += [a for a in first.ambiguities if a["alternative"]["name"] not in stick.added]
    starts = _onsets(ctx, found, ems, res, opts)
    if starts is not None and starts.total is not None:  # the arm refitted at the latency the starts pin
        found = _refit_arm_found(found, ems, res, new=latency.LATENCY_EFFECTS)
    peak = _peak_windows(ctx, found, ems, res, opts) if opts.stick_windows else None
    ambiguities, lookalikes, swaps = check_lookalikes(ems, res, opts)
    for eq, alt in swaps.items():  # the look-alike test favours the alternative: it becomes the equation's model
        r = res[eq]
        final = completed_pairs(ems[eq], significant(ems[eq], refit(ems[eq], alt.spec), r.trace), r.trace)
        res[eq] = EquationResult(eq, r.rows, r.nominal, final, r.trace, r.location)
        found = [f for f in found if not (f.equation == eq and f.source == "inverse dynamics")] + found_in(ems[eq], res[eq], [])
    if stick is not None:
        ambiguities += stick.ambiguities
        lookalikes += stick.lookalikes
    free_swing = swing.is_free_swing(prep, rig)
    decay = free_decay(prep, rig) if free_swing else None
    decay_json = None
    if decay is not None:
        found, ambiguities = _use_decay(decay, found, ambiguities, lookalikes, ctx.known)
        read = swing.read(prep, rig, decay.peaks_t, decay.rest_offset)
        notes += read.notes()
        decay_json = {**decay.as_json(), **read.as_json()}
    elif free_swing:
        notes.append(swing.TOO_FEW)
    gated = gate.run(ctx, ems, res, found, opts, notes, stick, peak)  # leaves res refitted without what it moved out
    found, below = practical.split(ctx, ems, res, gated.found, opts.seed)  # res refitted without the small ones
    if below:
        notes.append(practical.describe(below))
    dropped = {e["name"] for e in [*gated.not_predictive, *below]}
    ambiguities = [a for a in ambiguities if a["effects"][0] not in dropped]
    lookalikes = [a for a in lookalikes if a.get("reported") not in dropped]  # no look-alike of a removed effect
    lock = armlock.assess(prep, rig)  # the arm's rests: dry friction or a dead band (needs no regression rows)
    if lock is not None:
        notes += [lock.text(), *armlock.above_sliding(lock, {f.name: f.params for f in found})]
        ambiguities += armlock.declare(lock, [f.name for f in found], list(ctx.known),
                                       EXPERIMENTS[frozenset({"arm_coulomb", "input_deadzone"})])
    try:
        effects_of(found)
    except ValueError as err:  # e.g. a combination the effects vocabulary forbids
        notes.append(f"the found effects are not a consistent set ({err}); reported as found, not simulated")
    located = "; ".join(describe(r.location, list(r.selected.spec.effects)) for r in res.values())
    if stick is not None:
        located += "; " + stickslip.describe(stick, {f.name: f.params for f in found})
    if peak is not None and peak.added:
        located += "; " + peaks.describe(peak)
    prediction: dict = {}
    fit_summary = _prediction_metric(ctx, gated, found, prediction)
    closed = _closed_loop(rec, rig, found, opts, notes) if opts.closed_loop else None
    verdicts = verdict.assess(ctx, ems, res, opts.seed, found, gated.not_predictive)
    ident = identify.identification(ems[ARM], res[ARM].selected)
    for f in found:
        if f.source == "inverse dynamics":
            f.pinned, f.combinations = identify.pinning(ident, f.name)
    located = verdict.with_verdicts(located, res, verdicts)
    return Diagnosis(
        effects=found, fit=fit_summary, located=located, ambiguities=ambiguities, lookalikes=lookalikes,
        equations=res, closed_loop=closed, notes=notes, seconds=time.perf_counter() - t0, rig=rig.name, context=ctx,
        models=ems, prediction=prediction, decay=decay_json, decay_result=decay,
        stick=stick, peak=peak, starts=starts, not_predictive=gated.not_predictive, verdicts=verdicts,
        summary=verdict.summary(verdicts),
        identification=ident, below_practical=below, arm_lock=lock.as_json() if lock is not None else None,
    )


def _select(ctx: Context, eq: str, opts: Options, rows: np.ndarray | None = None) -> tuple[EquationModel, EquationResult]:
    """Forward selection and refit of one equation's effects (on ``rows`` of its usable rows, if given)."""
    em = EquationModel(ctx, eq, opts.thresholds, row_filter=rows)
    nominal, selected, trace = em.select()
    if selected.spec.effects:
        selected = refit(em, selected.spec)
    selected = completed_pairs(em, significant(em, latency.settle(em, selected, trace), trace), trace)
    loc = locate(ctx, eq, em.target(em.spec0()), em.row_mask)
    return em, EquationResult(eq, em.n_rows, nominal, selected, trace, loc)


def significant(em: EquationModel, ev: Evaluation, trace: list[dict] | None = None) -> Evaluation:
    """``ev`` without the effects that, in the final refitted model, are not significant or do not pay for themselves:
    the selection's rules (select.EquationModel.admissible: t ≥ t_min, or ≥ t_strong with a large held-out gain;
    physically admissible) and the backward pass's (removing it costs ≥ min_gain of the held-out error) applied once
    more after the refit, the latency and the look-alike swaps moved the parameters. The weakest is dropped and the
    rest refitted until all pass. Two arm effects whose estimates are collinear (|r| ≥ identify.COLLINEAR: an input
    gain and the damping on one constant step at one speed) are judged together — the combination they pin, not
    either alone (identify.pinning reports it) — when removing both costs ≥ 2·min_gain."""
    if em.n_rows < 20 * em.th.n_blocks:
        return ev
    while ev.spec.effects:
        names = [n for n in ev.spec.effects if not (n in LUGRE_CONTAINS and "arm_lugre" in ev.spec.effects)]
        pays = {n: _pays(em, ev, n) for n in names}
        failing = {n: p for n, p in pays.items() if not p[0]}
        for pair in identify.collinear_pairs(em, ev):
            if set(pair) & set(failing) and _pair_pays(em, ev, pair):
                for n in pair:
                    failing.pop(n, None)
        if not failing:
            group = [n for n in JOINT if n in ev.spec.effects]
            if len(group) < 2 or _group_pays(em, ev, group):
                return ev
            rest = ev.spec
            for n in group:
                rest = rest.without(n)
            if trace is not None:
                trace.append({"step": len(ev.spec.effects), "candidate": "+".join(group), "pair": group, "dropped": True,
                              "accepted": False, "ok": False, "t": 0.0, "value": None,
                              "params": {n: ev.params[n] for n in group}})
            ev = refit(em, rest)
            continue
        # first what is not significant or not physical (lowest t first), then what does not pay (lowest gain first)
        weakest = min(failing, key=lambda n: (failing[n][1], failing[n][3] if failing[n][1] else failing[n][2]))
        if trace is not None:
            trace.append({"step": len(ev.spec.effects), "candidate": weakest, "dropped": True, "cv_gain": failing[weakest][3],
                          "t": float(ev.t_stat.get(weakest, 0.0)), "params": ev.params[weakest], "accepted": False,
                          "ok": False, "value": em.nonlinear_value(ev.spec, weakest)})
        ev = refit(em, ev.spec.without(weakest))
    return ev


def _group_pays(em: EquationModel, ev: Evaluation, group: list[str]) -> bool:
    """Whether the arm's datasheet parameters in ``group`` (input gain, damping, inertia: select.JOINT) pay together.
    Each may look significant given the others when they compensate each other (a gain of 0.6 with an inertia of
    0.6×: the acceleration per command unchanged, only the pendulum's reaction on the arm rescaled), so the group is
    judged as one step: the model without all of them against the model with them (the inertia re-profiled in each
    held-out fold, as a single step's is), by the selection's rules — paired t over the blocks ≥ t_min, or a held-out
    gain ≥ strong_gain with t ≥ t_strong or gained in all blocks but one — and the BIC penalty of as many parameters.
    On an independent simulator's null recording a gain 0.61 + inertia 0.6× pair had removed 0.9 % of the held-out
    error at paired t < 1."""
    rest = ev.spec
    for n in group:
        rest = rest.without(n)
    without = em.evaluate(rest)
    full = fair_baseline(em, ev, "arm_inertia") if "arm_inertia" in group else ev
    gain = (without.cv - full.cv) / without.cv if without.cv else 0.0
    t = paired_t(without.fit.cv_block, full.fit.cv_block)
    th = em.th
    better = int(np.sum(np.asarray(full.fit.cv_block) < np.asarray(without.fit.cv_block)))
    blocks = len(full.fit.cv_block)
    # a large gain concentrated in a few blocks (a swing-up's) has a small paired t: then nearly every block must gain
    strong = gain >= th.strong_gain and (t >= th.t_strong or better >= blocks - 1)
    return bool((t >= th.t_min or strong) and without.cv - full.cv > em.bic_penalty(len(group), full.cv))


def completed_pairs(em: EquationModel, ev: Evaluation, trace: list[dict] | None = None) -> Evaluation:
    """``ev`` with the missing member of a pinnable pair (identify.PINNABLE_PAIRS: input gain and damping) added when the
    two would be collinear here and the pair fits as well: on a constant command at a constant speed an input gain
    alone is one point of a line of (gain, damping) that fit alike — g ≈ 0 with no friction (an arm coasting) as well
    as the true torque per volt against the true damping — so what the data says is the pair's ratio (the speed per
    volt), reported with both members and their uncertainty, not a gain at the damping the config assumes."""
    if em.n_rows < 20 * em.th.n_blocks:
        return ev
    for pair in identify.PINNABLE_PAIRS:
        have = [n for n in pair if n in ev.spec.effects]
        if len(have) != 1 or not all(em.can_add(ev.spec, n) for n in pair if n not in have):
            continue
        other = next(n for n in pair if n not in have)
        both = refit(em, ev.spec.with_effect(other))
        physical = all(CANDIDATES[n].plausible(both.params[n], em.ctx.rig, em.ctx.arm_travel) for n in pair)
        if physical and pair in identify.collinear_pairs(em, both) and both.cv <= ev.cv * (1 + em.th.min_gain):
            if trace is not None:
                trace.append({"step": len(ev.spec.effects), "candidate": other, "pair": list(pair), "completed": True,
                              "cv_gain": (ev.cv - both.cv) / ev.cv if ev.cv else 0.0, "t": float(both.t_stat.get(other, 0.0)),
                              "params": both.params[other], "accepted": True, "ok": True, "value": None})
            ev = both
    return ev


def _pays(em: EquationModel, ev: Evaluation, name: str) -> tuple[bool, bool, float, float]:
    """(whether ``name`` is significant, admissible and worth ≥ min_gain given the others; whether it is significant and
    admissible; its t; the held-out gain it brings)."""
    without = em.evaluate(ev.spec.without(name))
    gain = (without.cv - ev.cv) / without.cv if without.cv else 0.0
    t = float(ev.t_stat.get(name, 0.0))
    significant_t = np.isfinite(t) and (t >= em.th.t_min or (gain >= em.th.strong_gain and t >= em.th.t_strong))
    physical = name in em.ctx.known or CANDIDATES[name].plausible(ev.params[name], em.ctx.rig, em.ctx.arm_travel)
    return bool(significant_t and physical and gain >= em.th.min_gain), bool(significant_t and physical), t, gain


def _pair_pays(em: EquationModel, ev: Evaluation, pair: tuple[str, str]) -> bool:
    """Whether two collinear effects pay together: removing both costs ≥ 2·min_gain, both physically admissible."""
    without = em.evaluate(ev.spec.without(pair[0]).without(pair[1]))
    gain = (without.cv - ev.cv) / without.cv if without.cv else 0.0
    physical = all(n in em.ctx.known or CANDIDATES[n].plausible(ev.params[n], em.ctx.rig, em.ctx.arm_travel) for n in pair)
    return physical and gain >= 2 * em.th.min_gain


RESELECT_MIN_ROWS, RESELECT_MIN_SHARE = 1000, 0.25  # the arm regression without short stays, if this much is left


def _support(em: EquationModel, selected: Evaluation, opts: Options, kind: str, value: float) -> float | None:
    """The arm regression's held-out gain (on its sliding rows) when the command path's ``kind`` (delay, limit in
    command units) is set to ``value`` in the selected model; None when the arm equation has too few rows."""
    if em.n_rows < 20 * opts.thresholds.n_blocks or not selected.cv:
        return None
    name = {"delay": "input_delay", "limit": "input_saturation"}[kind]
    spec = selected.spec if name in selected.spec.effects else selected.spec.with_effect(name)
    ev = em.evaluate(spec.with_value(kind, value))
    return (selected.cv - ev.cv) / selected.cv


def _peak_windows(ctx: Context, found: list[Found], ems: dict[str, EquationModel], res: dict[str, EquationResult],
                  opts: Options) -> stickslip.WindowStage | None:
    """The command-peak stage (furuta_rt.diagnose.stages.peaks): an actuator limit, when the arm regression did not see
    most of the largest commands."""
    current = {**ctx.known, **{f.name: f.params for f in found}}
    if not ctx.prep.commanded or "input_saturation" in current or peaks.covered(ctx.prep, ems[ARM].row_mask) >= peaks.MIN_COVERED:
        return None
    gain = current.get("input_gain", {}).get("gain", ctx.known_gain)
    peak = peaks.assess(ctx.rig, current, ctx.prep, ctx.fine, opts.thresholds, ctx.stays(STILL_TICKS), ctx.fine.phi_dot,
                        lambda limit: _support(ems[ARM], res[ARM].selected, opts, "limit", limit / gain))
    if peak is not None:
        for name, params in peak.added.items():
            f = peak.fits[name]
            found.append(Found(name, ARM, params, {f.param: f.se}, f.t, f.gain, "peak windows"))
    return peak


def _stick_windows(ctx: Context, found: list[Found], ems: dict[str, EquationModel], res: dict[str, EquationResult],
                   opts: Options, only: set[str] | None = None, lugre: bool = True) -> stickslip.WindowStage | None:
    """The stick–slip stage (furuta_rt.diagnose.stages.stickslip): the arm's sticks and breakaways decide on a breakaway
    torque above the sliding level and time the actuator; without Coulomb friction found, on the sliding level too
    (from the arm regression's provisional fit of it)."""
    current = {**ctx.known, **{f.name: f.params for f in found}}
    coulomb = None if "arm_coulomb" in current else _provisional_coulomb(ems[ARM], res[ARM], opts)
    delay = next((f for f in found if f.name == "input_delay" and f.source == "inverse dynamics"), None)
    stick = stickslip.assess(ctx.rig, current, ctx.prep, ctx.fine, opts.thresholds,
                             lambda d: _support(ems[ARM], res[ARM].selected, opts, "delay", d), only=only, lugre=lugre,
                             coulomb=coulomb, delay_se=delay.se.get("delay") if delay is not None else None)
    if stick is not None:
        found[:] = [f for f in found if f.name not in stick.replaces]
        for name, params in stick.added.items():
            f = stick.fits[name]
            found.append(Found(name, ARM, params, {f.param: f.se}, f.t, f.gain, "stick windows"))
    return stick


def _retimed(stick: stickslip.WindowStage | None, found: list[Found], ems: dict[str, EquationModel],
             res: dict[str, EquationResult]) -> list[Found]:
    """With the regression's input_delay re-timed on the stick windows, the arm model refitted at that delay
    (latency.retimed) and its other effects reported from the refit; ``found`` as it was otherwise."""
    if stick is None or "input_delay" not in stick.replaces:
        return found
    r = res[ARM]
    res[ARM] = EquationResult(ARM, r.rows, r.nominal, latency.retimed(ems[ARM], r.selected, stick.added["input_delay"]["delay"]),
                              r.trace, r.location)
    return _refit_arm_found(found, ems, res, skip=("input_delay",))


def _refit_arm_found(found: list[Found], ems: dict[str, EquationModel], res: dict[str, EquationResult],
                     skip: tuple[str, ...] = (), new: tuple[str, ...] = ()) -> list[Found]:
    """``found`` with the arm regression's effects read again from its refitted model ``res[ARM]`` (``skip``: left
    as found, e.g. a delay a window stage reports; ``new``: effects the refit added, appended), every other effect as
    it was (one a window stage replaced stays out)."""
    fresh = {f.name: f for f in found_in(ems[ARM], res[ARM], []) if f.name not in skip}
    out = [fresh.get(f.name, f) if f.equation == ARM and f.source == "inverse dynamics" else f for f in found]
    return out + [fresh[n] for n in new if n in fresh]


def _onsets(ctx: Context, found: list[Found], ems: dict[str, EquationModel], res: dict[str, EquationResult],
            opts: Options) -> onset.OnsetTiming | None:
    """The arm's starts from rest (furuta_rt.diagnose.stages.onset), where no latency was found: with a total latency they
    pin, the arm model is refitted at it (latency._refit_at) with the latency among its effects."""
    if any(f.name in latency.LATENCY_EFFECTS for f in found) or ems[ARM].n_rows < 20 * opts.thresholds.n_blocks:
        return None
    timing = onset.assess(ctx.rig, {**ctx.known, **{f.name: f.params for f in found}}, ctx.prep, ctx.fine)
    if timing is None or timing.total is None:
        return timing
    value = timing.total - ctx.prep.command_lag  # path.delay: on top of the config's lag
    name = latency.effect_for(value)
    r = res[ARM]
    ev = latency._refit_at(ems[ARM], r.selected.spec.with_effect(name), value, r.selected)
    ev.t_stat[name] = abs(value) / timing.se
    ev.se[name] = {"delay": timing.se}
    res[ARM] = EquationResult(ARM, r.rows, r.nominal, ev, r.trace, r.location)
    r.trace.append({"step": len(ev.spec.effects), "candidate": "latency (arm starts)", "accepted": True, "ok": True,
                    "t": ev.t_stat[name], "value": value, "params": timing.as_json(), "cv_gain": 0.0})
    return timing


def _provisional_coulomb(em: EquationModel, r: EquationResult, opts: Options) -> float | None:
    """The arm regression's Coulomb level added to its selected model (None when the arm equation has too few rows
    or the level comes out ≤ 0, or no stick-window stage could use it)."""
    if em.n_rows < 20 * opts.thresholds.n_blocks or "arm_lugre" in r.selected.spec.effects:
        return None
    fc = em.evaluate_with(r.selected.spec, "arm_coulomb").params["arm_coulomb"]["Fc"]
    return fc if fc > 0 else None


PENDULUM_FRICTION = ("pendulum_viscous", "pendulum_coulomb")


def _decay_effects(fit: DecayFit) -> list[Found]:
    out = []
    if fit.bp > 0:
        out.append(Found("pendulum_viscous", PEND, {"bp": fit.bp}, {"bp": fit.se_bp}, fit.bp / (fit.se_bp or 1.0), 0.0,
                         "free decay"))
    if fit.Fc > 0:
        out.append(Found("pendulum_coulomb", PEND, {"Fc": fit.Fc}, {"Fc": fit.se_Fc}, fit.Fc / (fit.se_Fc or 1.0), 0.0,
                         "free decay"))
    return out


def _as_known(e: Found, known: dict[str, dict[str, float]]) -> bool:
    """Whether a found effect is the rig's own, at its configured value (within two standard errors)."""
    if e.name not in known:
        return False
    return all(abs(v - known[e.name].get(k, 0.0)) <= 2 * e.se.get(k, 0.0) for k, v in e.params.items())


def _use_decay(
    decay: DecayResult, found: list[Found], ambiguities: list[dict], lookalikes: list[dict],
    known: dict[str, dict[str, float]],
) -> tuple[list[Found], list[dict]]:
    """A free decay is the experiment that tells viscous from Coulomb pivot friction: its energy-per-cycle
    fit replaces the pendulum friction of the inverse-dynamics selection and settles their ambiguity."""
    f = {k: v.loo_rms for k, v in decay.fits.items()}
    pend = [e for e in _decay_effects(decay.fits[decay.best]) if not _as_known(e, known)]
    found = [e for e in found if e.name not in PENDULUM_FRICTION] + pend
    ambiguities = [a for a in ambiguities if not set(a["effects"]) <= set(PENDULUM_FRICTION)]
    lookalikes.append({
        "effects": list(PENDULUM_FRICTION), "reported": ", ".join(e.name for e in pend) or "none",
        "reason": f"the recording is a free decay of {decay.cycles} cycles: the energy lost per cycle is predicted within "
                  f"{100 * f['both']:.0f} % by viscous + Coulomb, {100 * f['viscous']:.0f} % by viscous alone, "
                  f"{100 * f['coulomb']:.0f} % by Coulomb alone (leave-one-cycle-out)",
        "experiment": EXPERIMENTS[frozenset(PENDULUM_FRICTION)],
    })
    return found, ambiguities


def _prediction_metric(ctx: Context, gated: gate.Gated, found: list[Found], keep: dict) -> dict:
    """The held-out fit (furuta_rt.diagnose.stages.gate): the nominal and the gated augmented model's predictions of the
    informative windows, and the verdict of their paired comparison."""
    plan, nominal_p, aug_p = gated.plan, gated.nominal, gated.augmented
    try:
        augmented = effects_of(found)
    except ValueError:
        augmented = Effects()
    keep.update(starts=plan.starts, horizon=plan.horizon, augmented=augmented, substep_hz=gated.substep_hz)
    t = ctx.prep.t
    return {
        "metric": verify.PREDICTION_METRIC, "nominal": nominal_p.nrmse, "augmented": aug_p.nrmse,
        **verify.compare(nominal_p, aug_p),
        "nominal_theta": nominal_p.nrmse_theta, "nominal_phi": nominal_p.nrmse_phi,
        "augmented_theta": aug_p.nrmse_theta, "augmented_phi": aug_p.nrmse_phi,
        "windows": nominal_p.windows, "window_times_s": [float(t[k] - t[0]) for k in plan.starts],
        "horizon_s": plan.horizon * ctx.prep.dt, "folds": plan.folds, "candidate_windows": plan.candidates,
        "held_out_from_s": float(t[plan.starts[0]] - t[0]) if plan.starts else float("nan"),
        "train_params": gated.fold_params,
    }


def _closed_loop(rec: Recording, rig: RigConfig, found: list[Found], opts: Options, notes: list[str]) -> dict | None:
    why = moving_start(rec) if rec.meta.get("stretch_of_log") else ""
    if why:
        notes.append(f"{why}; the closed-loop re-simulation starts from rest and is skipped")
        return None
    own, r2 = verify.is_own_closed_loop(rec, rig)
    if not own:
        if r2 > 0.5:
            notes.append(
                f"the commands are only partly the configured controller's (R² = {r2:.2f}); no closed-loop re-simulation"
            )
        return None
    data = verify.closed_loop_stats(rec)
    nominal = verify.closed_loop_stats(verify.resimulate(rec, rig, Effects(), opts.seed, opts.substep_hz))
    try:
        eff = effects_of(found)
    except ValueError:
        return {"data": data, "nominal": nominal, "augmented": None, "replay_r2": r2}
    augmented = verify.closed_loop_stats(verify.resimulate(rec, rig, eff, opts.seed, opts.substep_hz)) if found else nominal
    return {"data": data, "nominal": nominal, "augmented": augmented, "replay_r2": r2}


