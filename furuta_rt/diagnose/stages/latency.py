"""The command latency measured jointly with the arm's linear parameters.

The forward selection adds ``input_delay`` / ``command_latency`` as one candidate among others, profiled before the
gain, inertia and damping are in the model: the profile is then biased (a wrong gain or inertia moves the phase
too) and its fold-wise optima scatter. This stage runs on the arm equation's final selected model: the *total*
latency L (sample instant → torque acting) is profiled afresh on a grid from one tick below 0 to 50 ms, with every
linear parameter refitted at each lag (the held command is a kernel integral at any lag, so each point is one
least-squares fit), ΔJ included as one more linear column (ID is linear in J: lag and inertia trade phase, so
they are profiled together, not one after the other); ΔJ is then re-profiled in the selection's units at the lag.

The latency is reported when it differs from the config's significantly: the optimum at least ``MIN_TICKS`` of a
tick away, its held-out error (each block predicted at the lag best on the others) below the config's by ≥ 2·min_gain
and beyond the BIC penalty of one parameter, and either a likelihood ratio n_eff·ln(SSE_config/SSE_optimum) ≥ t_min²
(n_eff the independent residuals) or a held-out gain ≥ strong_gain. Not the selection's ≥ 5 % rule alone: a lag that
only shifts the phase of a slow response gains less, and not the fold-wise optima's scatter alone: on a chirp or a
swing-up the blocks carry very different timing information, and leaving out the one fast block moves the optimum.
A longer latency is an ``input_delay`` on top of ``command_delay_ticks·h``, a shorter
one a ``command_latency`` (the total); an optimum more than half a tick below 0 (acausal) is something else a lead
would mimic, and nothing is reported. Where the latency is not significant, a latency effect the selection took is
removed (the config's latency stands).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from furuta_rt.diagnose.regression.fitting import Stats, fit, fit_profiled
from furuta_rt.diagnose.regression.library import ARM, CANDIDATES
from furuta_rt.diagnose.regression.selection import EquationModel, Evaluation, Spec

LATENCY_EFFECTS = ("input_delay", "command_latency")
MIN_TICKS = 0.25  # a departure from the config's latency smaller than this is not named
MAX_DELAY = 0.05  # s on top of the config's lag (as select.EquationModel.grid("delay"))


def effect_for(value: float) -> str:
    """The latency effect that carries a command-path delay ``value`` (s) on top of the config's lag: a longer
    latency is an ``input_delay`` (of ``value``), a shorter one a ``command_latency`` (the total)."""
    return "input_delay" if value > 0 else "command_latency"


def _without_latency(spec: Spec) -> Spec:
    for name in LATENCY_EFFECTS:
        if name in spec.effects:
            spec = spec.without(name)
    return spec


def _backward(em: EquationModel, current: Evaluation, keep: str) -> Evaluation:
    """The selection's backward pass on the model with the latency found: an effect that stood in for the wrong
    latency (e.g. friction fitted to the phase error) and no longer lowers the held-out error by min_gain is dropped."""
    changed = True
    while changed and len(current.spec.effects) > 1:
        changed = False
        for name in current.spec.effects:
            if name == keep:
                continue
            reduced = em.evaluate(current.spec.without(name))
            if (reduced.cv - current.cv) / reduced.cv < em.th.min_gain:
                current, changed = reduced, True
                break
    return current


def _grid(em: EquationModel, centre: float | None = None) -> np.ndarray:
    """path.delay values (on top of the config's lag): totals from one tick below 0 to the lag + MAX_DELAY, one tick
    apart; with ``centre``, a quarter tick apart within two ticks of it."""
    prep = em.ctx.prep
    lag, h = prep.command_lag, prep.dt
    if centre is None:
        return np.arange(-lag - h, MAX_DELAY + 1e-12, h)
    return np.arange(max(centre - 2 * h, -lag - h), min(centre + 2 * h, MAX_DELAY) + 1e-12, 0.25 * h)


def settle(em: EquationModel, selected: Evaluation, trace: list[dict] | None = None) -> Evaluation:
    """``selected`` with the latency decided jointly with the arm's linear parameters (see the module docstring)."""
    ctx = em.ctx
    if em.equation != ARM or not ctx.prep.commanded or em.n_rows < 20 * em.th.n_blocks:
        return selected
    h, lag = ctx.prep.dt, ctx.prep.command_lag
    spec = _without_latency(selected.spec)
    null_delay = ctx.base_path.delay
    joint_j = "arm_inertia" in spec.effects
    # with ΔJ in the model, ΔJ as one more linear column (the arm's inverse dynamics is linear in J): the lag and ΔJ
    # are profiled jointly, not by coordinate descent along their correlated valley

    def stats_of(v: float) -> Stats:
        at = spec.with_value("delay", v)
        if not joint_j:
            return em.stats(at)[0]
        X, _ = em.design(replace(at, d_inertia=0.0))
        return Stats.of(em.target(replace(at, d_inertia=0.0)), np.column_stack([X, -ctx.arm_dJ]), em.blocks)

    _, value, _ = fit_profiled(stats_of, _grid(em))  # coarse, then fine around the coarse optimum
    f, value, folds = fit_profiled(stats_of, _grid(em, value))
    spec = spec.with_value("delay", value)
    at_config_fit = fit(stats_of(null_delay))
    B = len(folds)
    se = max(float(np.sqrt((B - 1) / B * np.sum((folds - folds.mean()) ** 2))), 0.05 * h)
    cv, cv0 = f.cv_sse, at_config_fit.cv_sse
    gain = (cv0 - cv) / cv0 if cv0 else 0.0
    total = lag + value
    far = abs(value - null_delay) >= MIN_TICKS * h
    causal = total >= -0.5 * h
    n_eff = max(em.n_rows / em.corr_len, 10.0)
    lr = n_eff * float(np.log(at_config_fit.sse / f.sse)) if f.sse > 0 else 0.0
    ok = (far and causal and gain >= 2 * em.th.min_gain and (lr >= em.th.t_min**2 or gain >= em.th.strong_gain)
          and cv0 - cv > em.bic_penalty(1, cv))
    name = effect_for(value)
    if trace is not None:
        trace.append({"step": len(selected.spec.effects), "candidate": "latency (joint)", "joint": True,
                      "cv_gain": gain, "t": abs(value - null_delay) / se, "params": {"total": total, "se": se, "lr": lr},
                      "accepted": ok, "ok": ok, "value": value})
    if not ok:
        if not any(n in selected.spec.effects for n in LATENCY_EFFECTS):
            return selected  # the config's latency stands, and so does the selected model
        return refit_at(em, spec, null_delay, selected)
    spec = spec.with_effect(name).with_value("delay", value)
    if joint_j:  # ΔJ in the selection's units (acceleration-weighted profile) at the lag found
        spec = em.evaluate_with(spec.without("arm_inertia"), "arm_inertia").spec
    out = _backward(em, em.evaluate(spec), name)
    # its significance is the test above (the likelihood ratio's signed root), not the fold-wise optima's scatter alone
    out.t_stat[name] = max(abs(value - null_delay) / se, float(np.sqrt(max(lr, 0.0))))
    out.se[name] = {"delay": se}
    kept = [k for k in out.spec.effects if CANDIDATES[k].nonlinear and k != name]
    out.t_stat.update({k: selected.t_stat[k] for k in kept if k in selected.t_stat})
    out.se.update({k: selected.se[k] for k in kept if k in selected.se})
    return out


def refit_at(em: EquationModel, spec: Spec, value: float, selected: Evaluation) -> Evaluation:
    """``spec`` with the command path's delay at ``value`` (on top of the config's lag), its linear parameters refitted
    and ΔJ re-profiled there (lag and inertia trade phase); the nonlinear parameters keep ``selected``'s t and se (from
    their profiles)."""
    spec = spec.with_value("delay", value)
    if "arm_inertia" in spec.effects:
        spec = em.evaluate_with(spec.without("arm_inertia"), "arm_inertia").spec
    out = em.evaluate(spec)
    kept = [k for k in out.spec.effects if CANDIDATES[k].nonlinear]
    out.t_stat.update({k: selected.t_stat[k] for k in kept if k in selected.t_stat})
    out.se.update({k: selected.se[k] for k in kept if k in selected.se})
    return out


def retimed(em: EquationModel, selected: Evaluation, delay: float) -> Evaluation:
    """The selected arm model at the ``input_delay`` another stage timed better (the stick windows: the breakaways time
    the actuator more directly than sliding rows that hold brief sticks, where the friction is the held torque, not
    ±Fc): the gain, damping and inertia reported beside that delay are fitted at it, not at the rows' own value."""
    if "input_delay" not in selected.spec.effects:
        return selected
    return refit_at(em, selected.spec, delay, selected)
