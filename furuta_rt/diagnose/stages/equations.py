"""Stage: each equation of eq. 4 (arm, pendulum) regressed on the library's effects — forward selection on held-out
time blocks (furuta_rt.diagnose.regression.selection), the nonlinear parameters re-profiled jointly (findings.refit),
the latency settled (stages.latency), and what is left judged once more: significant, paying for itself, a
collinear pair completed or judged together."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from furuta_rt.diagnose.judgement.locate import locate
from furuta_rt.diagnose.regression import identify
from furuta_rt.diagnose.regression.fitting import paired_t
from furuta_rt.diagnose.regression.library import ARM, CANDIDATES, PEND, Context
from furuta_rt.diagnose.regression.selection import JOINT, EquationModel, Evaluation
from furuta_rt.diagnose.stages import latency
from furuta_rt.diagnose.stages.findings import LUGRE_CONTAINS, EquationResult, Options, found_in, refit
from furuta_rt.diagnose.stages.state import State


def stage(s: State) -> State:
    """Both equations selected; their effects are the first findings."""
    ems: dict[str, EquationModel] = {}
    res: dict[str, EquationResult] = {}
    notes: list[str] = []
    for eq in (ARM, PEND):
        ems[eq], res[eq] = select_equation(s.ctx, eq, s.opts)
        if ems[eq].n_rows < 20 * s.opts.thresholds.n_blocks:
            notes.append(
                f"{eq} equation: only {ems[eq].n_rows} usable samples "
                + ("(the arm hardly moves: arm-side effects cannot be assessed; excite the arm, e.g. an arm reference)"
                   if eq == ARM else "")
            )
    found = [f for eq in res for f in found_in(ems[eq], res[eq], notes)]
    return s.with_(ems=ems, res=res).noted(*notes).replace_found(found)


def select_equation(ctx: Context, eq: str, opts: Options, rows: np.ndarray | None = None) -> tuple[EquationModel, EquationResult]:
    """Forward selection and refit of one equation's effects (on ``rows`` of its usable rows, if given)."""
    em = EquationModel(ctx, eq, opts.thresholds, row_filter=rows)
    r = select_in(em)
    return em, replace(r, location=locate(ctx, eq, em.target(em.spec0()), em.row_mask))


def select_in(em: EquationModel, settle_latency: bool = True) -> EquationResult:
    """``em``'s effects: forward selection, the nonlinear parameters re-profiled together (findings.refit), the latency
    settled (``settle_latency``: stages.latency reads one recording's time line, so a joint fit of several skips it),
    then the final significance pass and the collinear pairs (``significant``, ``completed_pairs``). No location:
    ``select_equation`` adds the recording's; a joint fit of several has none."""
    nominal, selected, trace = em.select()
    if selected.spec.effects:
        selected = refit(em, selected.spec)
    if settle_latency:
        selected = latency.settle(em, selected, trace)
    selected = completed_pairs(em, significant(em, selected, trace), trace)
    return EquationResult(em.equation, em.n_rows, nominal, selected, trace, None)  # type: ignore[arg-type]


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
    On a null recording a gain 0.61 + inertia 0.6× pair can remove 0.9 % of the held-out error at paired t < 1."""
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


def support(em: EquationModel, selected: Evaluation, opts: Options, kind: str, value: float) -> float | None:
    """The arm regression's held-out gain (on its sliding rows) when the command path's ``kind`` (delay, limit in
    command units) is set to ``value`` in the selected model; None when the arm equation has too few rows."""
    if em.n_rows < 20 * opts.thresholds.n_blocks or not selected.cv:
        return None
    name = {"delay": "input_delay", "limit": "input_saturation"}[kind]
    spec = selected.spec if name in selected.spec.effects else selected.spec.with_effect(name)
    ev = em.evaluate(spec.with_value(kind, value))
    return (selected.cv - ev.cv) / selected.cv




def fair_baseline(em: EquationModel, selected: Evaluation, name: str) -> Evaluation:
    """The selected model scored as its look-alike alternative is: ``name``'s nonlinear parameter (ΔJ, a delay, a
    width) re-profiled inside each held-out fold, as ``evaluate_with`` does for the alternative. The refitted
    selection holds that parameter at its full-data optimum, so its held-out error is optimistic next to a profiled
    alternative's (on a gain ↔ inertia tie that bias alone can read as paired t = 3.4 for the inertia)."""
    if not CANDIDATES[name].nonlinear:
        return selected
    return em.evaluate_with(selected.spec.without(name), name)
