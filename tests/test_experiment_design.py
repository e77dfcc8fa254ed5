"""Designed experiments, the design: a report's look-alike pair as two simulator models, candidate excitations
scored by diagnose's own test statistic on recordings of them simulated (closed loop through the one
Controller.update, with the rig's sensor noise) under each alternative, limits checked on the whole plan under both,
and `furuta-rt experiment design` as a user runs it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from furuta_rt.cli import main
from furuta_rt.config import load_rig
from furuta_rt.errors import UserError
from furuta_rt.experiment import hanging
from furuta_rt.experiment.design import alternatives_from_report, calibrated_score, design, score
from furuta_rt.experiment.plan import Plan, Segment, load_plan

# gain 0.8 on the command ↔ the arm inertia that gives the same β/gain at the thesis rig (β 0.0517 / 0.8: J 0.05 →
# 0.0629): the pair the blind recordings left "too close to tell" (paired t 0.9)
REPORT = {
    "effects": [{"name": "arm_inertia", "params": {"J": 0.0629}}],
    "ambiguities": [{"effects": ["arm_inertia", "input_gain"], "reported": "arm_inertia",
                     "alternative": {"name": "input_gain", "params": {"gain": 0.8}},
                     "alternative_model": {"input_gain": {"gain": 0.8}}, "paired_t": 0.9}],
}


def test_report_pair_becomes_two_models() -> None:
    alt = alternatives_from_report(REPORT)
    assert (alt.named, alt.rival, alt.passive_t) == ("arm_inertia", "input_gain", 0.9)
    assert alt.a == {"arm_inertia": {"J": 0.0629}} and alt.b == {"input_gain": {"gain": 0.8}}
    with pytest.raises(UserError, match="no unresolved look-alike"):
        alternatives_from_report({"effects": [], "ambiguities": []})
    with pytest.raises(UserError, match="--pair arm_coulomb,input_deadzone"):
        alternatives_from_report(REPORT, "arm_coulomb,input_deadzone")


def test_excitation_separates_what_balancing_alone_cannot() -> None:
    """Balancing at rest with nothing added predicts no separation (noise-free, from rest: nothing tells them
    apart); an arm sweep separates the pair (expected t > 5 both ways)."""
    rig = load_rig("thesis")
    alt = alternatives_from_report(REPORT)
    passive = score(rig, alt, Plan((Segment("hold", 2.0),), settle_s=0.2))
    sweep = score(rig, alt, Plan((Segment("sweep", 2.0, {"amplitude": 0.2, "speed": 0.4}),), settle_s=0.2))
    assert max(passive) < 0.5 and min(sweep) > 5.0, (passive, sweep)


def test_calibrated_score_is_diagnoses_kappa_test() -> None:
    """The score of gain ↔ inertia is κ's z, the statistic diagnose decides this pair by: 0 when the arm does not move
    (no arm rows: nothing to fit), below its threshold for a slow sweep (the pendulum hardly reacts) and above it
    for a fast one (its reversals swing the pendulum: the reaction κ scales is there to see)."""
    rig = load_rig("thesis")
    alt = alternatives_from_report(REPORT)
    hold = calibrated_score(rig, alt, Plan((Segment("hold", 4.0),), settle_s=0.5))
    assert [r["decisive"] for r in hold] == [0.0, 0.0] and hold[0]["test"] == "κ z" and hold[0]["threshold"] == 4.0
    slow = calibrated_score(rig, alt, Plan((Segment("sweep", 8.0, {"amplitude": 0.5, "speed": 0.1}),), settle_s=1.0))
    fast = calibrated_score(rig, alt, Plan((Segment("sweep", 8.0, {"amplitude": 0.5, "speed": 1.2}),), settle_s=1.0))
    assert max(r["decisive"] for r in slow) < 4.0 < max(r["decisive"] for r in fast), (slow, fast)
    assert min(r["decisive"] for r in fast) > 2 * max(r["decisive"] for r in slow)
    for r in fast:  # κ near 0 under the truth, the rival's prediction 1 − g (gain true) or 1 − 1/g (inertia true)
        assert abs(r["kappa"]) < 4 * r["se"] and r["kappa_z"] == r["decisive"]


def test_design_picks_the_best_candidate_within_limits_and_refuses_beyond() -> None:
    rig = load_rig("thesis")
    alt = alternatives_from_report(REPORT)
    family = [Plan((Segment("hold", 4.0),), settle_s=0.5),
              Plan((Segment("sweep", 4.0, {"amplitude": 0.5, "speed": 1.0}),), settle_s=0.5)]
    best, ranked = design(rig, alt, 4.0, eval_s=4.0, plans=family)
    assert ranked[-1][0] is family[0] and ranked[-1][1] == 0.0  # doing nothing ranks last: nothing to fit
    assert best.plan is family[1] and best.separation == ranked[0][1] > 0 and best.test == "κ z"
    assert best.peak_phi < rig.safety.phi_limit and best.peak_theta < rig.safety.theta_limit
    assert best.peak_u < rig.actuator.limit
    # a |φ| limit below the sweep's travel: it is refused, doing nothing is all that is left (and separates nothing)
    best_tight, _ = design(rig, alt, 4.0, eval_s=4.0, plans=family, limits=(0.1, 0.5, 2.0))
    assert best_tight.plan is family[0] and best_tight.separation == 0.0
    with pytest.raises(UserError, match="exceed"):
        design(rig, alt, 4.0, eval_s=4.0, plans=family[1:], limits=(0.1, 0.5, 2.0))


def test_cli_never_overwrites_a_plan_and_writes_a_loadable_one(tmp_path: Path, capsys: pytest.CaptureFixture,
                                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    import furuta_rt.experiment.design as d

    family = [Plan((Segment("sweep", 2.0, {"amplitude": 0.2, "speed": 0.4}),), settle_s=0.2)]
    monkeypatch.setattr(d, "candidate_plans", lambda rig, budget, settle_s=1.0: family)
    report = tmp_path / "report.json"
    report.write_text(json.dumps(REPORT))
    plan = tmp_path / "plan.toml"
    plan.write_text("mine")
    assert main(["experiment", "design", str(report), "-o", str(plan), "--budget", "2"]) == 2
    err = capsys.readouterr().err
    assert plan.read_text() == "mine" and "--force" in err and len(err.strip().splitlines()) == 1
    assert main(["experiment", "design", str(report), "-o", str(plan), "--budget", "2", "--force"]) == 0
    out = capsys.readouterr().out
    written = load_plan(plan)
    assert written.segments == family[0].segments and "arm_inertia from input_gain" in written.note
    for needle in ("look-alike: arm_inertia ↔ input_gain (paired t 0.9", "expected separation: κ z",
                   "worst under either or neither: |φ|", "--experiment"):
        assert needle in out, out


def test_hanging_chirp_separates_gain_from_inertia() -> None:
    """Open loop about θ = π: a torque chirp across the natural frequency (0.89 Hz for the thesis rig: eq. 6's
    ε/(α − γ²/β); the thesis measured the period 1.12 s with the arm held) swings the pendulum, and κ's test rejects the
    rival by ≥ its threshold in 8 s in both directions (balancing sweeps: below it in the same time). The swing and
    the arm's travel stay inside the hanging limits."""
    rig = load_rig("thesis")
    f = hanging.natural_frequency(rig)
    assert 1 / f == pytest.approx(1.12, rel=0.02)
    alt = alternatives_from_report(REPORT)
    plan = Plan((Segment("chirp", 8.0, {"amplitude": 0.03, "f0": 0.5 * f, "f1": 2 * f}),), mode="hanging", settle_s=1.0)
    ra, rb = calibrated_score(rig, alt, plan)
    assert min(ra["decisive"], rb["decisive"]) >= ra["threshold"] == 4.0, (ra, rb)
    rec = hanging.simulate(rig, alt.a, plan, 0, substep_hz=2000.0)
    assert 0.02 < hanging.swing(rec.theta) < hanging.SWING_LIMIT and np.max(np.abs(rec.phi)) < rig.safety.phi_limit
    assert np.all(rec.u[: int(rig.control.rate_hz)] == 0.0) and np.max(np.abs(rec.u)) == pytest.approx(0.03, rel=1e-3)
