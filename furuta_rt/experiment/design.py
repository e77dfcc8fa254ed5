"""Design the experiment that tells two look-alike explanations apart (`furuta-rt experiment design`).

A diagnose report names a look-alike pair when the recording cannot separate them: the model it reports (A) and an
alternative (B) that fits almost as well (its "ambiguities": the alternative's effects and parameters). Both are
physics the simulator runs (furuta_rt.sim.closed_loop with furuta_rt.model.effects), so each candidate excitation is
predicted under A and under B, closed loop, through the same ``Controller.update`` the rig runs.

The expected separation of a candidate is diagnose's own test statistic on simulated recordings of it: with A the
truth, the plan is simulated with the rig's sensor noise (seeded) and the pair judged on it by the code diagnose
judges it with (furuta_rt.diagnose.joint.pair_test: the paired t of the held-out block errors of B against A, and for
gain ↔ inertia the κ test's z, the standard errors by which κ rejects the rival's prediction); then with B the truth.
The smaller of the two directions is the candidate's score: a plan must separate the pair whichever is right. A
trajectory difference (``score``: the noise-whitened output residual after refitting the rival) is an upper bound
only: for input gain ↔ arm inertia only the pendulum's reaction on the arm (γ θ̈ in eq. 4's arm equation, scaled by
a gain, not by an inertia) separates them, and the trajectories differ by far more than that term.

Candidates are scored on ``eval_s`` seconds and the score scaled by √(budget/eval_s) (a stationary excitation gains
as the square root of its length); a chirp is scored whole (shortened, it would sweep through a resonance too fast
for the swing to build up). The chosen plan is then simulated whole under either alternative and under neither for
the worst |φ|, |θ|, |u|, and refused if one exceeds the rig's limits.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from furuta_rt.config import RigConfig
from furuta_rt.errors import UserError
from furuta_rt.experiment import hanging
from furuta_rt.experiment.plan import Excitation, Plan, Segment
from furuta_rt.model.effects import Effects

SUBSTEP_HZ = 2000.0  # the design's simulator substeps (the prediction, not the benchmark: 4× fewer than the default)


@dataclass(frozen=True)
class Alternatives:
    """The two explanations a report could not separate, as simulator physics."""

    named: str  # the effect the report names
    rival: str  # its look-alike
    a: dict[str, dict[str, float]]  # all effects with the named one
    b: dict[str, dict[str, float]]  # all effects with the rival in its place
    passive_t: float | None  # the report's paired t on the recording


@dataclass(frozen=True)
class Prediction:
    plan: Plan
    separation: float  # expected decisive statistic (the smaller direction): diagnose's paired t, or κ's z
    separation_ab: tuple[float, float]  # (A true, B true)
    test: str  # which statistic ("paired t" or "κ z")
    threshold: float  # the value at which diagnose tells the pair apart
    peak_phi: float
    peak_theta: float
    peak_u: float


def alternatives_from_report(report: dict[str, Any], pair: str | None = None) -> Alternatives:
    """The report's unresolved look-alike (``pair`` "a,b" picks one when there are several)."""
    try:
        found = {e["name"]: dict(e["params"]) for e in report.get("effects") or []}
        amb = [a for a in report.get("ambiguities") or [] if a.get("alternative")]
        for a in amb:
            _ = a["effects"][1], a["alternative"]["params"]  # the fields read below
    except (KeyError, TypeError, IndexError, AttributeError) as err:
        raise UserError(f"the report's effects or ambiguities are not diagnose's ({type(err).__name__}: {err})") from None
    if pair is not None:
        want = set(pair.split(","))
        amb = [a for a in amb if set(a["effects"]) == want]
        if not amb:
            raise UserError(f"--pair {pair}: the report has no unresolved look-alike of these two")
    if not amb:
        raise UserError("the report has no unresolved look-alike (its 'ambiguities' are empty): nothing to separate")
    entry = amb[0]
    named, rival = entry["effects"][0], entry["effects"][1]
    a = dict(found)
    b = {k: v for k, v in found.items() if k != named}
    b.update({k: dict(v) for k, v in (entry.get("alternative_model") or {}).items()})
    b[rival] = dict(entry["alternative"]["params"])
    b.pop(named, None)
    for label, effects in (("reported", a), ("alternative", b)):
        try:
            Effects.model_validate(effects)
        except ValueError as err:
            raise UserError(f"the report's {label} model cannot be simulated: {str(err).splitlines()[0]}") from None
    return Alternatives(named, rival, a, b, entry.get("paired_t"))


def candidate_plans(rig: RigConfig, budget_s: float, settle_s: float = 1.0) -> list[Plan]:
    """The family searched: constant-velocity sweeps, arm-reference steps, chirps and dithers on u, and a slow
    sweep with a dither, each filling the budget. Amplitudes are fractions of the rig's |u| limit; arm travel of
    ±0.2 and ±0.5 rad."""
    u_lim = rig.actuator.limit
    plans: list[Plan] = []

    def add(*segments: Segment) -> None:
        plans.append(Plan(tuple(segments), settle_s=settle_s))

    for amp in (0.2, 0.5):
        for speed in (0.1, 0.4, 0.8, 1.2):
            add(Segment("sweep", budget_s, {"amplitude": amp, "speed": speed}))
        n = 6
        add(*(Segment("step", budget_s / n, {"phi": amp if i % 2 == 0 else -amp}) for i in range(n)))
    for frac in (0.02, 0.05):
        add(Segment("chirp", budget_s, {"amplitude": frac * u_lim, "f0": 0.2, "f1": 3.0}))
        for hz in (1.0, 5.0):
            add(Segment("dither", budget_s, {"amplitude": frac * u_lim, "frequency": hz}))
        add(Segment("sweep", budget_s, {"amplitude": 0.3, "speed": 0.1, "dither": frac * u_lim, "dither_hz": 5.0}))
    return plans


def _shortened(plan: Plan, seconds: float) -> Plan:
    """The plan's first ``seconds`` (segments scaled in proportion), for scoring."""
    scale = min(1.0, seconds / sum(s.duration for s in plan.segments))
    return Plan(tuple(Segment(s.kind, s.duration * scale, s.params) for s in plan.segments), plan.mode, plan.settle_s,
                plan.return_speed)


def _noise_free(rig: RigConfig) -> RigConfig:
    """The rig without sensor noise: the prediction is the response to the excitation alone (the noise's own
    response is not known in advance and separates nothing; the noise enters as σ in ``_outputs``)."""
    sensors = rig.sensors.model_copy(update={"theta_noise": 0.0, "theta_dot_noise": 0.0})
    return rig.model_copy(update={"sensors": sensors})


def _simulate(rig: RigConfig, effects: dict[str, dict[str, float]], plan: Plan, seed: int) -> Any:
    """The plan under ``effects``, from rest upright (no arming transient) or hanging, noise-free."""
    from furuta_rt.sim.closed_loop import run_closed_loop

    if plan.mode == "hanging":
        return hanging.simulate(rig, effects, plan, seed, substep_hz=SUBSTEP_HZ, noise=False)
    exc = Excitation(plan, rig.control.rate_hz)
    return run_closed_loop(_noise_free(rig), exc.ticks / rig.control.rate_hz, effects=Effects.model_validate(effects),
                           excitation=exc, seed=seed, substep_hz=SUBSTEP_HZ, x0=(0.0, 0.0, 0.0, 0.0))


def _outputs(rig: RigConfig, rec: Any) -> np.ndarray:
    """(φ/σ_φ, θ/σ_θ) of the excitation's ticks (the settling before it excluded)."""
    sigma_phi = 2 * math.pi / rig.sensors.encoder_counts_per_rev / math.sqrt(12.0)
    sigma_theta = max(rig.sensors.theta_noise, rig.sensors.theta_rad_per_count / math.sqrt(12.0))
    return np.concatenate([rec.phi / sigma_phi, rec.theta / sigma_theta])


def _refit_residual(rig: RigConfig, truth: np.ndarray, model: dict[str, dict[str, float]], name: str,
                    plan: Plan, seed: int) -> float:
    """‖truth − model*‖ after one Gauss–Newton step on ``name``'s parameters (finite differences)."""
    y0 = _outputs(rig, _simulate(rig, model, plan, seed))
    params = model[name]
    cols = []
    for key, value in params.items():
        step = 0.05 * abs(value) if value else 1e-3
        moved = {**model, name: {**params, key: value + step}}
        try:
            cols.append((_outputs(rig, _simulate(rig, moved, plan, seed)) - y0) / step)
        except ValueError:  # a parameter at its bound: not refitted
            continue
    r = truth - y0
    if cols:
        jac = np.stack(cols, axis=1)
        delta, *_ = np.linalg.lstsq(jac, r, rcond=None)
        r = r - jac @ delta
    return float(np.linalg.norm(r))


def score(rig: RigConfig, alt: Alternatives, plan: Plan, seed: int = 0) -> tuple[float, float]:
    """Expected paired t (A true, B refitted; B true, A refitted) of ``plan``."""
    ya = _outputs(rig, _simulate(rig, alt.a, plan, seed))
    yb = _outputs(rig, _simulate(rig, alt.b, plan, seed))
    t_ab = _refit_residual(rig, ya, alt.b, alt.rival, plan, seed) / 2.0
    t_ba = _refit_residual(rig, yb, alt.a, alt.named, plan, seed) / 2.0
    return t_ab, t_ba


def _recording(rig: RigConfig, effects: dict[str, dict[str, float]], plan: Plan, seed: int) -> Any:
    """The plan under ``effects`` with the rig's sensor noise (seeded): what the rig would record, settling included."""
    from furuta_rt.sim.closed_loop import run_closed_loop

    if plan.mode == "hanging":
        return hanging.simulate(rig, effects, plan, seed, substep_hz=SUBSTEP_HZ)
    exc = Excitation(plan, rig.control.rate_hz)
    return run_closed_loop(rig, exc.ticks / rig.control.rate_hz, effects=Effects.model_validate(effects),
                           excitation=exc, seed=seed, substep_hz=SUBSTEP_HZ, x0=(0.0, 0.0, 0.0, 0.0))


def diagnose_test(rig: RigConfig, rec: Any, truth: str, rival: str, shared: dict[str, dict[str, float]]) -> dict:
    """diagnose's look-alike statistics for ``truth`` against ``rival`` on recording ``rec`` (joint.pair_test on the
    truth's equation, with ``shared``, the effects both alternatives have, in the base model)."""
    from furuta_rt.diagnose.joint import context, pair_test
    from furuta_rt.diagnose.regression.library import CANDIDATES
    from furuta_rt.diagnose.regression.selection import EquationModel
    from furuta_rt.diagnose.stages.findings import Options

    opts = Options()
    eq = CANDIDATES[truth].equation
    em = EquationModel(context(rec, rig, opts, []), eq, opts.thresholds)
    base = em.spec0()
    for name in shared:
        if name in CANDIDATES and CANDIDATES[name].equation == eq and em.can_add(base, name):
            base = base.with_effect(name)
    return pair_test(em, truth, rival, base)


def calibrated_score(rig: RigConfig, alt: Alternatives, plan: Plan, seed: int = 0) -> tuple[dict, dict]:
    """diagnose_test on the plan simulated with A the truth, then B (noisy, seeded)."""
    shared = {k: v for k, v in alt.a.items() if k in alt.b and k not in (alt.named, alt.rival)}
    ra = diagnose_test(rig, _recording(rig, alt.a, plan, seed), alt.named, alt.rival, shared)
    rb = diagnose_test(rig, _recording(rig, alt.b, plan, seed + 1), alt.rival, alt.named, shared)
    return ra, rb


def peaks(rig: RigConfig, alt: Alternatives, plan: Plan, seed: int = 0) -> tuple[float, float, float]:
    """Worst |φ|, |θ| (hanging: |θ − π|), |u| of the whole plan under either alternative or neither (the effects the
    two share: the pair may be a false alarm), settling and the return included. Open loop the arm's travel depends
    on the model most: a chirp that turns the arm 10 rad under either alternative turned it 12 rad with neither."""
    out = [0.0, 0.0, 0.0]
    neither = {k: v for k, v in alt.a.items() if k in alt.b and k not in (alt.named, alt.rival)}
    for effects in (alt.a, alt.b, neither):
        rec = _simulate(rig, effects, plan, seed)
        theta = hanging.swing(rec.theta) if plan.mode == "hanging" else float(np.max(np.abs(rec.theta)))
        for i, x in enumerate((float(np.max(np.abs(rec.phi))), theta, float(np.max(np.abs(rec.u))))):
            out[i] = max(out[i], x)
    return out[0], out[1], out[2]


def design(rig: RigConfig, alt: Alternatives, budget_s: float, *, eval_s: float = 8.0,
           limits: tuple[float, float, float] | None = None, plans: list[Plan] | None = None,
           progress: Any = None, seed: int = 0, mode: str = "balancing") -> tuple[Prediction, list[tuple[Plan, float]]]:
    """The candidate with the largest expected decisive statistic (calibrated_score on its first ``eval_s`` seconds,
    scaled by √(budget/eval_s): both statistics grow as the square root of the rows) that keeps within ``limits``
    (|φ|, |θ|, |u|; default the rig's); all candidates' scores, best first. Raises UserError if no candidate keeps
    within the limits. ``mode`` "hanging": the family of experiment.hanging, |θ| measured from hanging (default
    limit hanging.SWING_LIMIT)."""
    swing_lim = hanging.SWING_LIMIT if mode == "hanging" else rig.safety.theta_limit
    phi_lim, theta_lim, u_lim = limits or (rig.safety.phi_limit, swing_lim, rig.actuator.limit)
    if plans is not None:
        family = plans
    else:
        family = hanging.candidate_plans(rig, budget_s) if mode == "hanging" else candidate_plans(rig, budget_s)
    scored: list[tuple[Plan, float, tuple[float, float], dict]] = []
    for i, plan in enumerate(family):
        # a chirp is not stationary (shortened, it runs through a resonance too fast to build the swing up): whole
        short = plan if any(s.kind == "chirp" for s in plan.segments) else _shortened(plan, eval_s)
        ra, rb = calibrated_score(rig, alt, short, seed)
        grow = math.sqrt(sum(s.duration for s in plan.segments) / sum(s.duration for s in short.segments))
        ab = (max(ra["decisive"], 0.0) * grow, max(rb["decisive"], 0.0) * grow)
        scored.append((plan, min(ab), ab, ra))
        if progress is not None:
            progress(i + 1, len(family), plan, min(ab))
    scored.sort(key=lambda x: -x[1])
    refused = []
    for plan, sep, ab, ra in scored:
        phi, theta, u = peaks(rig, alt, plan)
        if phi < phi_lim and theta < theta_lim and u < u_lim:
            return (Prediction(plan, sep, ab, ra["test"], ra["threshold"], phi, theta, u),
                    [(p, s) for p, s, _, _ in scored])
        refused.append(f"{plan.segments[0].describe()}: |φ| {phi:.3g}, |θ| {theta:.3g}, |u| {u:.3g}")
        if len(refused) >= 3:
            break
    raise UserError(f"the {len(refused)} best candidates exceed |φ| < {phi_lim:g} rad, |θ| < {theta_lim:g} rad or "
                    f"|u| < {u_lim:g} under one of the alternatives (the best: {refused[0]}); a shorter budget or "
                    "looser limits")
