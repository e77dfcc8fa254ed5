"""`diagnose a b …`: several recordings of one rig fitted jointly (furuta_rt.diagnose.joint).

The case is the one the blind recordings left open: an input gain of 0.8 on the thesis rig looks, while balancing,
like an arm inertia of J/0.8 (both give the same acceleration per command; only the pendulum's reaction on the arm,
scaled by a gain and not by an inertia, tells them apart, and balancing alone hardly moves the pendulum). The passive
recording leaves the pair unresolved, and so does the first designed experiment (a fast constant-velocity arm sweep
within the rig's limits: κ's test short of its threshold); the three together decide it. A rig without the effect,
recorded passively and with one sweep, gets no effect named."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from furuta_rt.cli import main
from furuta_rt.config import load_rig
from furuta_rt.diagnose import Options, diagnose
from furuta_rt.diagnose.joint import JointDiagnosis
from furuta_rt.diagnose.jointly import diagnose_joint
from furuta_rt.diagnose.stages.lookalikes import SEPARATION_Z
from furuta_rt.experiment.plan import Excitation, Plan, Segment
from furuta_rt.io.csv import write_csv
from furuta_rt.model.effects import Effects
from furuta_rt.sim.closed_loop import run_closed_loop

GAIN = 0.8
SWEEP = Plan((Segment("sweep", 30.0, {"amplitude": 0.5, "speed": 1.2}),), settle_s=1.0)
PAIR = {"input_gain", "arm_inertia"}


def recordings(effects: dict, sweeps: tuple[int, ...] = (2, 3)) -> list[tuple[str, object]]:
    rig = load_rig("thesis")
    eff = Effects.model_validate(effects)
    out = [("passive", run_closed_loop(rig, 20.0, effects=eff, seed=1, substep_hz=2000))]
    for seed in sweeps:
        exc = Excitation(SWEEP, rig.control.rate_hz)
        out.append((f"sweep{seed}", run_closed_loop(rig, exc.ticks / rig.control.rate_hz, effects=eff, seed=seed,
                                                    substep_hz=2000, excitation=exc, x0=(0.0, 0.0, 0.0, 0.0))))
    return out


def joint(recs: list[tuple[str, object]]) -> JointDiagnosis:
    """The joint diagnosis, each recording's own without the stick-window stage (no arm sticks here; it is a third
    of a single diagnosis's time) and none with the closed-loop re-simulation."""
    rig = load_rig("thesis")
    singles = [diagnose(rec, rig, Options(closed_loop=False, stick_windows=False)) for _, rec in recs]
    return diagnose_joint(recs, rig, Options(closed_loop=False), singles=singles)


@pytest.fixture(scope="module")
def gain_recordings() -> list[tuple[str, object]]:
    return recordings({"input_gain": {"gain": GAIN}})


@pytest.fixture(scope="module")
def gain_case(gain_recordings: list[tuple[str, object]]) -> JointDiagnosis:
    return joint(gain_recordings)


@pytest.fixture(scope="module")
def null_case() -> JointDiagnosis:
    return joint(recordings({}, (2,)))


def test_sweeps_stay_within_the_rig_limits(gain_recordings: list[tuple[str, object]]) -> None:
    rig = load_rig("thesis")
    for _, rec in gain_recordings[1:]:
        assert np.max(np.abs(rec.u)) < rig.actuator.limit and np.max(np.abs(rec.theta)) < rig.safety.theta_limit
        assert np.max(np.abs(rec.phi)) < rig.safety.phi_limit


# four diagnoses of 20–31 s recordings (three alone, one joint) in the fixture: 270 s at load 11 on two cores
@pytest.mark.timeout(900)
def test_alone_unresolved_jointly_the_gain(gain_case: JointDiagnosis) -> None:
    for alone in gain_case.singles[:2]:  # the passive recording, the first sweep
        assert any(set(a["effects"]) == PAIR for a in alone.ambiguities), alone.ambiguities
    # the joint fit names the gain, within four of its standard errors of the truth
    gain = next(e for e in gain_case.effects if e.name == "input_gain")
    assert "arm_inertia" not in gain_case.names
    assert abs(gain.params["gain"] - GAIN) <= 4 * gain.se["gain"], (gain.params, gain.se)
    # the passive recording alone named the inertia, which the joint fit does not
    assert {"recording": "passive", "alone_only": ["arm_inertia"], "joint_only": ["input_gain"]} in gain_case.changes()
    pair = next(p for p in gain_case.pairs if set(p["effects"]) == PAIR)
    assert pair["status"] == "resolved" and pair["reported"] == "input_gain", pair
    # decided by κ: the rival's prediction rejected by ≥ SEPARATION_Z standard errors, the gain's consistent
    told = next(a for a in gain_case.lookalikes if set(a["effects"]) == PAIR)
    sep = told["separation"]
    assert sep["verdict"] == "selected" and abs(sep["kappa"] - sep["predicted_alternative"]) >= SEPARATION_Z * sep["se"]
    assert sep["predicted_alternative"] == pytest.approx(1 - GAIN, abs=4 * gain.se["gain"])


@pytest.mark.timeout(900)
def test_null_rig_names_nothing(null_case: JointDiagnosis) -> None:
    assert null_case.effects == [], [(e.name, e.params) for e in null_case.effects]
    assert not null_case.ambiguities and all(p["reported"] == "none" for p in null_case.pairs)


def test_unresolved_pair_says_how_much_more_data() -> None:
    """The passive recording and a slow sweep (0.1 rad/s: the pendulum hardly reacts) leave the pair unresolved;
    the report gives the factor of rows κ's test needs, from its standard error and the rival's prediction."""
    from furuta_rt.diagnose.joint import needed_factor

    entry = {"paired_t": 0.8, "cv_difference": 0.002,
             "separation": {"kappa": 0.03, "se": 0.05, "predicted_alternative": 0.2}}
    # κ must end SEPARATION_Z errors from the rival's 0.2 (now 0.17 away) → (4·0.05/0.17)²; the paired t cannot (the
    # held-out errors differ by 0.2 % only, below ambiguity_gain, which more rows do not change)
    assert needed_factor(entry, Options()) == pytest.approx((SEPARATION_Z * 0.05 / 0.17) ** 2)
    # a pair the held-out errors separate by ≥ ambiguity_gain, at paired t 1.5: (3 / 1.5)² the rows
    assert needed_factor({"paired_t": 1.5, "cv_difference": 0.02}, Options()) == pytest.approx(4.0)
    assert needed_factor({"paired_t": 0.5, "cv_difference": 0.001}, Options()) == float("inf")


def test_cli_joint_json_and_refusals(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    paths = []
    for i, (name, rec) in enumerate(recordings({}, (2,))):
        p = tmp_path / f"{name}.csv"
        write_csv(rec.slice(0, 4000) if i else rec.slice(0, 3000), p)
        paths.append(str(p))
    out = tmp_path / "joint.json"
    assert main(["diagnose", *paths, "--json", str(out), "--no-closed-loop"]) == 0
    text = capsys.readouterr().out
    assert "joint diagnosis of 2 recordings" in text
    data = json.loads(out.read_text())
    assert data["joint"] is True and data["recordings"] == paths and len(data["single"]) == 2
    assert data["rows"]["pendulum"][0] > 0 and data["rows"]["pendulum"][1] > 0
    for argv, needle in ((["diagnose", paths[0], paths[0]], "given twice"),
                         (["diagnose", *paths, "--report", str(tmp_path / "rep")], "--report"),
                         (["diagnose", *paths, "--json", str(out)], "--force")):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert needle in err and len(err.strip().splitlines()) == 1, err


def test_spring_constant_is_per_recording(monkeypatch: pytest.MonkeyPatch) -> None:
    """A cable spring −k(φ − φ0) on two runs whose arm encoders were zeroed 0.2 rad apart: k is the rig's (one column),
    k·φ0 the run's (one column per recording, zero on the other's rows); both φ0 read back within four standard
    errors, and one shared constant fits the two runs worse."""
    from furuta_rt.diagnose import joint
    from furuta_rt.diagnose.regression.selection import EquationModel

    rig, k = load_rig("thesis"), 0.05
    t = np.arange(5000) / rig.control.rate_hz
    ref = 0.3 * np.sin(2 * np.pi * t / 3.0) + 0.15 * np.sin(2 * np.pi * t / 1.1)
    recs = [run_closed_loop(rig, 10.0, effects=Effects.model_validate({"arm_spring": {"k": k, "phi0": phi0}}),
                            seed=20 + i, reference=ref, substep_hz=2000) for i, phi0 in enumerate((0.0, 0.2))]
    opts = Options()
    em = joint.JointEquationModel([EquationModel(joint.context(r, rig, opts, []), "arm", opts.thresholds) for r in recs])
    spec = em.spec0().with_effect("arm_spring")
    X, owners = em.design(spec)
    n0 = em.members[0].ctx.prep.n
    assert X.shape[1] == 3 and dict(owners)["arm_spring"] == slice(0, 2)
    assert np.all(X[n0:, 1] == 0.0) and np.all(X[:n0, 2] == 0.0) and np.all(X[n0:, 2] == 1.0)
    ev = em.evaluate(spec)
    kh, se_k = ev.params["arm_spring"]["k"], ev.se["arm_spring"]["k"]
    assert abs(kh - k) <= 4 * se_k, (kh, se_k)
    c, se_c = ev.fit.coef, ev.fit.se  # (−φ: k, 1: k·φ0 of the first run, 1: k·φ0 of the second)
    assert abs(c[1] - k * 0.0) <= 4 * se_c[1] and abs(c[2] - k * 0.2) <= 4 * se_c[2], (c, se_c)
    monkeypatch.setattr(joint, "PER_RECORDING", {})
    shared = em.evaluate(spec)
    assert shared.fit.cv_sse > 1.5 * ev.fit.cv_sse, (shared.fit.cv_sse, ev.fit.cv_sse)
