"""Stages: the arm's sticks and breakaways (furuta_rt.diagnose.stages.stickslip) decide on a breakaway torque above
the sliding level and time the actuator; without Coulomb friction found, on the sliding level too (from the arm
regression's provisional fit of it) — ``first_reading``.

With a breakaway above the sliding level the arm may also stick briefly at reversals, where its friction is the held
torque, not ±Fc: the arm regression is then redone without any short stay at one count (``reselect``), and the windows
are read a second time on top of the sliding level found there (``second_reading``; what the first reading compared
stays on record)."""

from __future__ import annotations

from dataclasses import replace

from furuta_rt.diagnose.regression.library import ARM, STICTION_STILL_TICKS
from furuta_rt.diagnose.regression.selection import EquationModel
from furuta_rt.diagnose.stages import latency, stickslip
from furuta_rt.diagnose.stages.equations import select_equation, support
from furuta_rt.diagnose.stages.findings import EquationResult, Found, Options, found_in
from furuta_rt.diagnose.stages.state import State

RESELECT_MIN_ROWS, RESELECT_MIN_SHARE = 1000, 0.25  # the arm regression without short stays, if this much is left


def first_reading(s: State) -> State:
    """The stick windows read on the regression's arm model (LuGre is tried in the second reading only)."""
    return read(s, lugre=False) if s.opts.stick_windows else s


def _breakaway(first: stickslip.WindowStage | None) -> bool:
    """The first reading found a breakaway above the sliding level (stiction, or LuGre's Stribeck peak)."""
    return first is not None and bool({"arm_stiction", "arm_lugre"} & set(first.added))


def reselect(s: State) -> State:
    """After a breakaway: the arm regression without the short stays, when enough rows are left."""
    if not _breakaway(s.stick):
        return s
    ctx, opts = s.ctx, s.opts
    em, r = select_equation(ctx, ARM, opts, ctx.clear_of(ctx.stays(STICTION_STILL_TICKS)))
    if "arm_coulomb" in r.selected.spec.effects and em.n_rows >= max(RESELECT_MIN_ROWS, RESELECT_MIN_SHARE * s.ems[ARM].n_rows):
        s = s.with_result(ARM, r, em).noted(
            f"arm equation: with a breakaway above the sliding level, stays of ≥ {STICTION_STILL_TICKS} ticks at "
            f"one encoder count are left out too (they may be short sticks); {em.n_rows} rows")
    # the regression's effects as they are now (a delay the windows re-timed among them)
    return s.replace_found(f for eq in s.res for f in found_in(s.ems[eq], s.res[eq], []))


def second_reading(s: State) -> State:
    """After a breakaway: the windows read again on the reselected arm model, both readings' comparisons on record."""
    first = s.stick
    if not _breakaway(first):
        return s
    s = read(s, only=set(first.added))
    if s.stick is None:
        return s
    second = s.stick
    return s.with_(stick=replace(
        second,
        tried=[{**t, "pass": 1} for t in first.tried] + [{**t, "pass": 2} for t in second.tried],
        lookalikes=second.lookalikes + [a for a in first.lookalikes if a["effects"][1] not in second.added],
        ambiguities=second.ambiguities + [a for a in first.ambiguities if a["alternative"]["name"] not in second.added],
    ))


def read(s: State, only: set[str] | None = None, lugre: bool = True) -> State:
    """One reading of the stick windows: ``s.stick`` set, the effects it replaces dropped, those it adds found, and
    a regression delay it re-timed carried into the arm model."""
    delay = next((f for f in s.found if f.name == "input_delay" and f.source == "inverse dynamics"), None)
    arm, selected = s.ems[ARM], s.res[ARM].selected
    stick = stickslip.assess(s.rig, s.current, s.ctx.prep, s.ctx.fine, s.opts.thresholds,
                             lambda d: support(arm, selected, s.opts, "delay", d), only=only, lugre=lugre,
                             coulomb=None if "arm_coulomb" in s.current else provisional_coulomb(arm, s.res[ARM], s.opts),
                             delay_se=delay.se.get("delay") if delay is not None else None)
    s = s.with_(stick=stick)
    if stick is None:
        return s
    s = s.drop(stick.replaces).add(*(
        Found(name, ARM, params, {stick.fits[name].param: stick.fits[name].se}, stick.fits[name].t,
              stick.fits[name].gain, "stick windows")
        for name, params in stick.added.items()))
    if "input_delay" not in stick.replaces:
        return s
    # the regression's input_delay re-timed on the stick windows: the arm model refitted at that delay, its other
    # effects reported from the refit
    r = s.res[ARM]
    retimed = latency.retimed(arm, r.selected, stick.added["input_delay"]["delay"])
    return s.with_result(ARM, EquationResult(ARM, r.rows, r.nominal, retimed, r.trace, r.location)).reread(
        ARM, skip=("input_delay",))


def provisional_coulomb(em: EquationModel, r: EquationResult, opts: Options) -> float | None:
    """The arm regression's Coulomb level added to its selected model (None when the arm equation has too few rows
    or the level comes out ≤ 0, or no stick-window stage could use it)."""
    if em.n_rows < 20 * opts.thresholds.n_blocks or "arm_lugre" in r.selected.spec.effects:
        return None
    fc = em.evaluate_with(r.selected.spec, "arm_coulomb").params["arm_coulomb"]["Fc"]
    return fc if fc > 0 else None
