"""Conventions of a recording checked against eq. 4 before the diagnosis: the signs of θ, φ and u, and the
angle units.

Eq. 4 ties the columns together (thesis section 2.2; FurutaPlant.inverse_dynamics is the one definition):

* pendulum row: α θ̈ + γ cos θ φ̈ − α φ̇² sin θ cos θ − ε sin θ = τ_pend (pivot friction only, no input). With θ
  reversed (θ → −θ) every term but the coupling γ cos θ φ̈ changes sign, so the row balances only with the
  coupling reversed; φ reversed reverses the coupling alone. The row tells whether θ and φ have the same sense
  as the rig's, not which one is off.
* arm row: … + (β + α sin² θ) φ̈ = g·u − friction. With φ or u reversed the fitted input gain is negative.

So: pendulum row reversed, arm gain positive → θ reversed; both reversed → φ reversed; only the gain → u (or
θ and φ together, the mirror image of the rig, which eq. 4 cannot tell from u reversed).

Where the command is constant while the arm moves (a voltage step, a spinning arm) the arm row's gain is confounded
with the friction and not identified; there the energy balance decides: g·∫k u φ̇ dt = ΔE + D with D ≥ 0 (friction
and back EMF only dissipate), so a command that did net negative work on an arm that turned more than a revolution
(no cable spring to store it) while the rig kept its energy means a negative torque per command.

Units: an angle logged in degrees and read as radians makes the pendulum row balance only after the angle is
scaled by π/180 (exactly in the linear terms for one angle alone; through sin θ and the centrifugal term for
both), and a hanging pendulum rest at θ ≈ ±180, which is no rest angle in radians.

Every hypothesis is scored by the pendulum row's rms residual relative to its torque scale (the rms of its terms),
after the pivot friction (viscous and Coulomb columns) is fitted; an alternative is declared only when it balances
the row and the recording as read clearly does not (``STRONG``), and mentioned in a note when it merely fits
better. Nothing is declared from a recording that cannot show it (a still pendulum, a still arm, a constant
command).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from furuta_rt.config import RigConfig
from furuta_rt.diagnose.regression.states import Prepared, States
from furuta_rt.errors import UserError
from furuta_rt.model.plant import FurutaPlant
from furuta_rt.model.rig import RigModel

SIGMA = 0.04  # s, the kernel width of the checks (between the arm's and the pendulum's)
DEG = math.pi / 180.0
STRONG = 0.4  # an alternative must leave at most this share of the as-read residual ...
BALANCED = 0.5  # ... and itself at most this share of the row's torque scale
TIE = 1.25  # hypotheses within this factor of the best fit the row alike (e.g. φ's units when the arm is still)
HINT = 0.7  # a better fit by this much (not strong): a note
GAIN_T = 6.0  # |t| of a negative input gain (block standard error) to declare it
N_BLOCKS = 10
ROW_STEP = 0.008  # s between the rows the checks use
REST_DEGREES = (170.0, 190.0)  # |θ| at rest read as this: hanging, in degrees
WORK_GAIN_FLOOR = 0.01  # a torque per command below this share of the config's is not a rig that was run


@dataclass(frozen=True)
class Hypothesis:
    """How the columns relate to the rig's convention: θ_rig = theta_sign·theta_scale·θ, φ_rig = phi_scale·φ."""

    theta_scale: float = 1.0
    phi_scale: float = 1.0
    theta_sign: float = 1.0

    @property
    def units(self) -> list[str]:
        return [n for n, s in (("θ", self.theta_scale), ("φ", self.phi_scale)) if s != 1.0]


AS_READ = Hypothesis()


def _terms(plant: FurutaPlant, th: np.ndarray, thd: np.ndarray, thdd: np.ndarray, phd: np.ndarray,
           phdd: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """(pendulum-row torque, arm-row torque, the pendulum row's torque scale) from the shared inverse dynamics;
    the scale is the rms of the row's terms, each isolated by zeroing the others' inputs."""
    z = np.zeros_like(th)
    tp, ta = plant.inverse_dynamics(th, thd, phd, thdd, phdd)
    grav, _ = plant.inverse_dynamics(th, z, z, z, z)
    parts = [grav, plant.inverse_dynamics(th, z, z, thdd, z)[0] - grav, plant.inverse_dynamics(th, z, z, z, phdd)[0] - grav,
             plant.inverse_dynamics(th, thd, phd, z, z)[0] - grav]
    scale = math.sqrt(sum(float(np.mean(p**2)) for p in parts))
    return tp, ta, scale


def _lstsq(y: np.ndarray, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    return coef, y - X @ coef


@dataclass
class Score:
    hypothesis: Hypothesis
    relative: float  # pendulum-row rms residual / its torque scale
    arm_gain: float | None = None  # fitted input gain / the config's
    arm_t: float | None = None


def _score(h: Hypothesis, st: States, plant: FurutaPlant, offset: float, rows: np.ndarray) -> tuple[Score, np.ndarray]:
    k = h.theta_sign * h.theta_scale
    th = k * st.theta - offset
    thd, thdd = k * st.theta_dot, k * st.theta_ddot
    phd, phdd = h.phi_scale * st.phi_dot, h.phi_scale * st.phi_ddot
    tp, ta, scale = _terms(plant, th[rows], thd[rows], thdd[rows], phd[rows], phdd[rows])
    _, res = _lstsq(tp, np.column_stack([thd[rows], np.tanh(thd[rows] / 0.05)]))
    rel = float(np.sqrt(np.mean(res**2))) / scale if scale > 0 else math.inf
    return Score(h, rel), ta


def _arm_gain(ta: np.ndarray, st: States, prep: Prepared, rows: np.ndarray, h: Hypothesis,
              known_gain: float) -> tuple[float, float]:
    """(input gain / the config's, its t) of the arm row, friction (viscous, Coulomb, bias) fitted alongside; the
    standard error from the spread over contiguous blocks."""
    u = st.held(prep.u, prep.command_lag)[rows]
    phd = h.phi_scale * st.phi_dot[rows]
    X = np.column_stack([u, phd, np.tanh(phd / 0.05), np.ones_like(u)])
    coef, _ = _lstsq(ta, X)
    blocks = np.array_split(np.arange(len(u)), N_BLOCKS)
    per = [(_lstsq(np.delete(ta, b), np.delete(X, b, axis=0))[0][0]) for b in blocks]  # jackknife
    se = math.sqrt((N_BLOCKS - 1) / N_BLOCKS * float(np.sum((np.array(per) - np.mean(per)) ** 2)))
    g = float(coef[0]) / known_gain
    return g, (float(coef[0]) / se if se > 0 else math.copysign(math.inf, g))


def _command_work(st: States, prep: Prepared, h: Hypothesis, model: RigModel) -> tuple[float, float, float] | None:
    """(W, ΔE, travel) of the energy balance g·W = ΔE + D: W = ∫ k·u·φ̇ dt the work the command does at the
    config's torque per command k, ΔE the change of eq. 4's mechanical energy (FurutaPlant.energy), D ≥ 0 what
    friction and the motor's back EMF dissipate (g: the true torque per command over the config's), summed over
    the recording's contiguous stretches clear of the filter's edges; travel is the arm's ptp. None when there is
    no such stretch. With g > 0 the rig can only lose energy where W < 0, at least g·|W| of it."""
    a = model.actuator
    k = a.gain * (a.motor.torque_per_volt if a.kind == "dc_motor" and a.motor is not None else 1.0)
    kt = h.theta_sign * h.theta_scale
    th, thd, phd = kt * st.theta - model.theta_offset, kt * st.theta_dot, h.phi_scale * st.phi_dot
    power = k * st.held(prep.u, prep.command_lag) * phd
    edges = np.flatnonzero(np.diff(np.concatenate([[0], prep.valid.astype(np.int8), [0]])))
    work = gained = 0.0
    for i0, i1 in zip(edges[::2], edges[1::2], strict=True):
        if i1 - i0 < 2:
            continue
        work += float(np.sum(power[i0:i1])) * prep.dt
        e = model.plant.energy(th[[i0, i1 - 1]], thd[[i0, i1 - 1]], phd[[i0, i1 - 1]])
        gained += float(e[1] - e[0])
    if work == 0.0:
        return None
    return work, gained, float(np.ptp(h.phi_scale * st.phi[prep.valid]))


def _work_sign(work: tuple[float, float, float] | None) -> tuple[float, str] | None:
    """(sign of the torque per command, the evidence) from the energy balance g·W = ΔE + D, or None. Decisive on an
    arm that turned more than a revolution (no cable spring can store work there) when the rig did not lose the
    energy the other sign needs: with W < 0 a positive g would be at most max(−ΔE, 0)/|W| × the config's, with
    W > 0 a negative g at least as small (both below WORK_GAIN_FLOOR)."""
    if work is None:
        return None
    w, de, travel = work
    bound = max(-de, 0.0) / abs(w)
    if travel < 2 * math.pi or bound >= WORK_GAIN_FLOOR:
        return None
    sign = 1.0 if w > 0 else -1.0
    did = f"the command did {w:+.3g} J of work on the arm (at the config's torque per command)"
    other = "negative" if w > 0 else "positive"
    if de >= 0:
        why = (f"while the rig's energy rose by {de:.3g} J: with friction only dissipating, a {other} torque per command "
               "cannot do that")
    else:
        why = (f"while the rig lost only {-de:.3g} J: with friction only dissipating, a {other} torque per command would "
               f"have to be below {bound:.2g} × the config's in size")
    return sign, f"{did} {why}"


def _moves(x: np.ndarray, lsb: float, counts: int = 50) -> bool:
    return bool(np.ptp(x) >= counts * lsb)


def conventions(prep: Prepared, rig: RigConfig) -> list[str]:
    """Check the recording's sign and unit conventions against the rig's (see the module docstring). Raises a
    one-line UserError saying what to change when the evidence is strong; returns notes otherwise."""
    prep = prep.as_recorded()  # the angles' units show in their recorded values (θ = 180 at rest)
    notes: list[str] = []
    model = RigModel.from_config(rig)
    rows = prep.valid
    u = prep.u[rows]
    if float(np.ptp(u)) == 0.0:
        notes.append(f"the command is constant where the recording is analysed (u = {u[0] + 0.0:.4g}): the command path "
                     "(input gain, delay, deadzone, limit) cannot be assessed")
    st = prep.states(SIGMA)
    rows = rows & (np.arange(prep.n) % max(1, round(ROW_STEP / prep.dt)) == 0)  # the σ = 40 ms signals are smooth
    rest = _rest_in_degrees(st.theta[rows], st.theta_dot[rows])
    moves = _moves(st.theta[rows], prep.phi_lsb, 2) or _moves(st.phi[rows], prep.phi_lsb, 2)
    if not moves and rest is None:
        return notes  # nothing moves: nothing to tell
    scores: dict[Hypothesis, Score] = {}
    arm_torque: dict[Hypothesis, np.ndarray] = {}
    for ts in (1.0, DEG):
        for ps in (1.0, DEG):
            for sign in (1.0, -1.0):
                h = Hypothesis(ts, ps, sign)
                scores[h], arm_torque[h] = _score(h, st, model.plant, model.theta_offset, rows)
    if rest is not None:  # θ in degrees; φ too if the pendulum row then balances decisively better with φ × π/180
        with_phi = min(scores[Hypothesis(DEG, DEG, 1.0)], scores[Hypothesis(DEG, DEG, -1.0)], key=lambda s: s.relative)
        without = min(scores[Hypothesis(DEG, 1.0, 1.0)], scores[Hypothesis(DEG, 1.0, -1.0)], key=lambda s: s.relative)
        both = moves and with_phi.relative <= STRONG * without.relative and with_phi.relative <= BALANCED
        also = (f", and with θ × π/180 eq. 4's pendulum row balances only with φ × π/180 too (residual "
                f"{100 * with_phi.relative:.0f} % of its torque scale against {100 * without.relative:.0f} %)") if both else ""
        fix = _fix("theta", DEG) + (f"; {_fix('phi', DEG, short=True)}" if both else "")
        raise UserError(f"{'θ and φ appear' if both else 'θ appears'} to be in degrees: the pendulum rests at "
                        f"θ = {rest:+.1f}, hanging in degrees (no rest angle in radians){also}; {fix}")
    here = min(scores[AS_READ], scores[Hypothesis(theta_sign=-1.0)], key=lambda s: s.relative)  # radians, either sign
    least = min(s.relative for s in scores.values())  # of the near-best, the one that changes fewest units
    best = min((s for s in scores.values() if s.relative <= TIE * least), key=lambda s: (len(s.hypothesis.units), s.relative))
    strong = best.relative <= STRONG * here.relative and best.relative <= BALANCED
    if strong and best.hypothesis.units:
        names = " and ".join(best.hypothesis.units)
        fix = "; ".join(_fix(n, DEG) for n, s in (("theta", best.hypothesis.theta_scale), ("phi", best.hypothesis.phi_scale))
                        if s != 1.0)
        raise UserError(f"{names} appear{'s' if len(best.hypothesis.units) == 1 else ''} to be in degrees: eq. 4's pendulum "
                        f"row balances only with {names} × π/180 (residual {100 * best.relative:.0f} % of its torque scale, "
                        f"{100 * here.relative:.0f} % as read); {fix}")
    units = best.hypothesis if strong else AS_READ
    same = scores[Hypothesis(units.theta_scale, units.phi_scale, 1.0)]
    flipped = scores[Hypothesis(units.theta_scale, units.phi_scale, -1.0)]
    pend_reversed = flipped.relative <= STRONG * same.relative and flipped.relative <= BALANCED
    if not pend_reversed and flipped.relative <= HINT * same.relative:
        notes.append(f"the pendulum row of eq. 4 fits somewhat better with θ reversed relative to φ (residual "
                     f"{100 * flipped.relative:.0f} % against {100 * same.relative:.0f} % of its torque scale); not decisive — "
                     "check the signs of θ and φ if the diagnosis looks wrong")
    chosen = flipped if pend_reversed else same
    gain = None
    if prep.commanded and float(np.std(prep.u[rows])) > 0 and _moves(st.phi[rows], prep.phi_lsb):
        gain = _arm_gain(arm_torque[chosen.hypothesis], st, prep, rows, chosen.hypothesis, model.actuator.gain)
    pend_text = (f"eq. 4's pendulum row balances only with the coupling γ cos θ φ̈ reversed (residual "
                 f"{100 * flipped.relative:.0f} % of its torque scale, {100 * same.relative:.0f} % as read)")
    arm_text = "" if gain is None else f"the arm row's input gain is {gain[0]:+.2f} × the config's (t = {gain[1]:+.0f})"
    arm_sign = None if gain is None or abs(gain[1]) < GAIN_T else math.copysign(1.0, gain[0])  # decisive, or None
    by_work = _work_sign(_command_work(st, prep, chosen.hypothesis, model)) if prep.commanded else None
    if by_work is not None and arm_sign is None:  # a step or a spin: the regression's gain is not identified there
        arm_sign, arm_text = by_work
    arm_reversed = arm_sign == -1.0
    if pend_reversed and arm_reversed:
        raise UserError(f"the sign of φ appears reversed relative to the rig: {pend_text}, and {arm_text}; {_fix('phi', -1)}")
    if pend_reversed and arm_sign == 1.0:
        raise UserError(f"the sign of θ appears reversed relative to the rig: {pend_text}, while {arm_text}; "
                        f"{_fix('theta', -1)}")
    if pend_reversed:
        why = (f"{arm_text}, not decisive" if gain is not None else "the command does not vary or the arm does not move")
        raise UserError(f"the sign of θ or of φ appears reversed relative to the rig: {pend_text} (the arm row cannot "
                        f"tell which: {why}); {_fix('theta', -1)} or {_fix('phi', -1, short=True)}")
    pend_as_read = same.relative <= STRONG * flipped.relative and same.relative <= BALANCED  # θ, φ agree (decisively)
    if arm_reversed and pend_as_read:
        raise UserError(f"the sign of u appears reversed relative to the rig (or θ and φ both are): {arm_text}, while the "
                        f"pendulum row balances as read (residual {100 * same.relative:.0f} % of its torque scale, "
                        f"{100 * flipped.relative:.0f} % with θ reversed); {_fix('u', -1)}")
    if arm_reversed:
        raise UserError(f"the sign of u or of φ appears reversed relative to the rig: {arm_text}, and the pendulum row "
                        f"cannot tell which (residual {100 * same.relative:.0f} % of its torque scale as read, "
                        f"{100 * flipped.relative:.0f} % with θ reversed); {_fix('u', -1)} or {_fix('phi', -1, short=True)}")
    if arm_sign is None and gain is not None and gain[0] < 0 and gain[1] < -2:
        notes.append(f"{arm_text}: a negative gain, not decisive — check the sign of u and φ if the diagnosis looks wrong")
    return notes


def _rest_in_degrees(theta: np.ndarray, theta_dot: np.ndarray) -> float | None:
    """θ's median where the (filtered) pendulum is at rest, when that reads as hanging in degrees (and is no rest
    angle in radians); else None."""
    lo, hi = REST_DEGREES
    still = np.abs(theta_dot) < 0.5  # per second, in whatever unit θ has
    if still.mean() < 0.5:
        return None
    rest = float(np.median(theta[still]))
    from_multiple_of_pi = abs(rest - math.pi * round(rest / math.pi))
    return rest if lo <= abs(rest) <= hi and from_multiple_of_pi > 0.3 else None


def _fix(column: str, factor: float, short: bool = False) -> str:
    opt = f"--map {column}.scale={factor:.9g}"
    if short:
        return opt
    what = "flip it" if factor == -1 else "convert it"
    also = " (θ's scale applies to theta_dot too)" if column == "theta" else ""
    return (f"{what} with {opt}{also} (with a --mapping: multiply its {column}.scale by {factor:.9g}; "
            "docs/RECORDINGS.md) or fix the logger; --skip-convention-check diagnoses it as read")
