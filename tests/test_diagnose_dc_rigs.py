"""`diagnose` on an independent voltage-driven rig (benchmarks.suite_independent_dc), and the two pieces of the
held-out metric that such recordings exposed: folds that train on every part of the recording (gate.make_plan), and a
verdict that heavy-tailed per-window errors do not hide (verify.compare)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from benchmarks import suite_independent_dc as dc
from benchmarks.suite import score_realistic
from furuta_rt.config import load_rig
from furuta_rt.diagnose import Options, diagnose
from furuta_rt.diagnose.judgement import verify
from furuta_rt.diagnose.stages import gate


def prediction(errors: list[float], diverged: int = 0) -> verify.Prediction:
    e = np.asarray(errors, float)
    flags = np.zeros(len(e), bool)
    flags[:diverged] = True
    return verify.Prediction(e, e, flags, 1.0, 1.0)


def test_two_runaway_windows_do_not_hide_a_better_prediction_everywhere_else() -> None:
    """The nominal model runs away in 2 of 40 windows (error 0.7) and is 1.5× worse in the other 38: the raw paired t
    is about 1.5 (the two dominate its spread), the paired t of the logarithms is large — improved. The same errors
    the other way round are worse, and a difference within the windows' scatter is unchanged."""
    rng = np.random.default_rng(0)
    good = 0.002 * np.exp(0.3 * rng.standard_normal(40))
    bad = np.concatenate([[0.7, 0.7], 1.5 * good[2:]])
    c = verify.compare(prediction(list(bad), diverged=2), prediction(list(good)))
    assert c["paired_t"] < verify.T_DIFFERENT < c["paired_t_log"]
    assert c["verdict"] == "improved"
    assert verify.compare(prediction(list(good)), prediction(list(bad), diverged=2))["verdict"] == "diverges"
    assert verify.compare(prediction(list(good)), prediction(list(1.5 * good)))["verdict"] == "worse"
    other = 1.02 * np.roll(good, 1)  # 2 % higher on average, window by window as scattered as the errors themselves
    c = verify.compare(prediction(list(good)), prediction(list(other)))
    assert abs(c["paired_t"]) < verify.T_DIFFERENT and abs(c["paired_t_log"]) < verify.T_DIFFERENT
    assert c["verdict"] == "unchanged"


def test_every_fold_trains_on_every_part_of_the_recording() -> None:
    """Windows are dealt to the folds in turn: each fold's training rows reach into every quarter of the recording
    (a swing-up in the first seconds is in every fold's training set), and no window's own samples are in its fold's
    training rows."""
    n, dt = 15000, 0.002
    prep = SimpleNamespace(n=n, dt=dt)
    starts = list(range(200, n - 400, 370))
    verify_starts = verify.informative_starts
    try:
        verify.informative_starts = lambda prep, horizon, max_windows: (starts, len(starts))  # type: ignore[assignment]
        plan = gate.make_plan(prep, load_rig("thesis"), 40, horizon_s=0.15)
    finally:
        verify.informative_starts = verify_starts  # type: ignore[assignment]
    assert plan.folds == gate.N_FOLDS
    for f in range(plan.folds):
        quarters = [plan.train[f][q * n // 4:(q + 1) * n // 4].mean() for q in range(4)]
        assert min(quarters) > 0.3, quarters
        for i, s in enumerate(plan.starts):
            if plan.fold_of[i] == f:
                assert not plan.train[f][s:s + plan.horizon + 1].any()
                assert not plan.outside(f, s, s + plan.horizon)


@pytest.mark.parametrize("name", ["macstepien/swingup amp×6.5 latency 0"])
def test_a_voltage_rig_swing_up_from_an_independent_simulator(name: str, tmp_path) -> None:
    """30 s of the independent macstepien-shaped rig (torque per volt 6.5× its datasheet, arm damping 0.0115, pendulum
    damping 1.8e-5, the command acting at once where the config says one tick), swung up from hanging and balanced:
    the arm's speed per volt and time constant within 20 %, the pendulum damping within 20 %, the latency within half
    a tick, nothing else, and the held-out prediction improved. The pendulum damping is excited only in the swing-up
    (the first second): with contiguous folds the fold holding it was predicted with 6.6e-4 fitted on the balance and
    the damping was dropped as not predictive."""
    case = next(c for c in dc.cases() if c.name == name)
    d = diagnose(dc.generate(case, 30.0, tmp_path), load_rig(case.shape), Options(closed_loop=False)).to_json()
    s = score_realistic(case, d, 0.0)  # type: ignore[arg-type]
    assert all(s.detected.values()), (s.detected, s.errors)
    assert s.false == [], s.false
    assert d["fit"]["verdict"] == "improved", d["fit"]
    assert d["equations"]["arm"]["verdict"] == "explained"


def test_a_balancing_recording_claims_no_arm_combination_it_cannot_pin(tmp_path) -> None:
    """30 s of the independent QUBE-shaped rig balancing, nothing changed from its datasheet: nothing found, both
    equations consistent, and the arm's joint calibration either gives the true speed per volt and time constant
    (within 20 %) or says it pins nothing — the arm barely moves, and the joint fit had traded gain, inertia and
    damping against the pendulum's reaction (arm inertia −3.2e-5 kg m²) and reported a speed per volt of 37 ± 1.4
    rad/s per V against a true 24."""
    case = next(c for c in dc.cases() if c.name == "qube/balance null")
    d = diagnose(dc.generate(case, 30.0, tmp_path), load_rig(case.shape), Options(closed_loop=False)).to_json()
    assert d["effects"] == []
    assert {eq: v["verdict"] for eq, v in d["equations"].items()} == {"arm": "consistent", "pendulum": "consistent"}
    ident = d["identification"]
    s = score_realistic(case, d, 0.0)  # type: ignore[arg-type]
    assert ident.get("unphysical") or all(s.detected.values()), (ident, s.errors)
    if ident.get("unphysical"):
        assert ident["combinations"] == {} and not any(p["pinned"] for p in ident["parameters"].values())


def test_a_pendulum_length_error_names_no_effect_and_points_at_the_length(tmp_path) -> None:
    """30 s of the independent QUBE-shaped rig balancing with its pendulum's centre of mass 15 % further out than the
    config's (outside the library): no effect named, both equations left unexplained, the first possible cause the
    pendulum's centre of mass (the run gives l2 = 1.162 × config against a true 1.15). The stick windows had held the
    arm at its encoder count with a Coulomb level of 1.2e-5 N m standing in for the model's creep; in an equation the
    band test shows to hold dynamics outside eq. 4, such a window-stage effect must now predict the held-out windows
    better, and does not."""
    case = next(c for c in dc.cases() if c.name == "qube/balance l2+15%")
    d = diagnose(dc.generate(case, 30.0, tmp_path), load_rig(case.shape), Options(closed_loop=False)).to_json()
    assert d["effects"] == [], d["effects"]
    assert "arm_coulomb" in [m["name"] for m in d["not_predictive"]]
    pend = d["equations"]["pendulum"]
    assert pend["verdict"] in ("partly_explained", "unexplained")
    first = pend["unexplained"]["possible_causes"][0]
    assert first["key"] == "l2", first
