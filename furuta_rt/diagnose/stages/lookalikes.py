"""Stage: each selected effect against its look-alikes. Where the data cannot tell the two apart both are reported
with the experiment that would (gain ↔ inertia decided by the κ test when it can); where the data favours the
look-alike, it becomes the equation's model."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from furuta_rt.diagnose.regression.fitting import Stats, fit, paired_t
from furuta_rt.diagnose.regression.library import CANDIDATES
from furuta_rt.diagnose.regression.selection import JOINT, EquationModel, Evaluation
from furuta_rt.diagnose.stages.equations import completed_pairs, fair_baseline, significant
from furuta_rt.diagnose.stages.findings import EquationResult, Options, found_in, refit
from furuta_rt.diagnose.stages.rest import bias_at_rest as rest_test
from furuta_rt.diagnose.stages.state import State
from furuta_rt.model.effects import EFFECT_TYPES


def stage(s: State) -> State:
    """The look-alike checks; an equation whose look-alike alternative the data favours is refitted with it."""
    ambiguities, lookalikes, swaps = check_lookalikes(s.ems, s.res, s.opts)
    for eq, alt in swaps.items():
        em = s.ems[eq]
        s = s.with_result(eq, swapped(em, s.res[eq], alt))
        s = s.replace_found([f for f in s.found if not (f.equation == eq and f.source == "inverse dynamics")]
                            + found_in(em, s.res[eq], []))
    if s.stick is not None:  # the stick windows' own look-alikes
        ambiguities += s.stick.ambiguities
        lookalikes += s.stick.lookalikes
    return s.with_(ambiguities=ambiguities, lookalikes=lookalikes)


def swapped(em: EquationModel, r: EquationResult, alt: Evaluation) -> EquationResult:
    """Equation result ``r`` with its look-alike alternative ``alt`` as the model: refitted, then the final
    significance pass and the collinear pairs, its trace a copy of the selection's continued by those checks."""
    trace = list(r.trace)
    final = completed_pairs(em, significant(em, refit(em, alt.spec), trace), trace)
    return EquationResult(r.equation, r.rows, r.nominal, final, trace, r.location)


EXPERIMENTS: dict[frozenset[str], str] = {
    frozenset({name, other}): text for name, cls in EFFECT_TYPES.items() for other, text in cls.experiments.items()
}  # the experiment that tells two effects apart, from the registry (furuta_rt.model.effects)


def check_lookalikes(
    ems: Mapping[str, EquationModel], res: Mapping[str, EquationResult], opts: Options
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

