"""The arm's datasheet parameters calibrated together before the greedy steps (select.EquationModel.joint_first) and
the profile ends that are no estimate (EquationModel.inside), on voltage-driven recordings of the QUBE-shaped rig; and
the one quantiser."""

from __future__ import annotations

import math

import numpy as np
import pytest

from furuta_rt.config import load_rig
from furuta_rt.diagnose import Options
from furuta_rt.diagnose.regression.library import ARM, Context
from furuta_rt.diagnose.regression.selection import EquationModel
from furuta_rt.diagnose.regression.states import prepare
from furuta_rt.diagnose.stages.start import arm_sigma
from furuta_rt.model.effects import effects_from_assignments
from furuta_rt.model.sensors import Calibration, count_of, quantise

QUBE_J = 6.19e-5  # the config's arm inertia (Quanser's Jr + rotor + hub)


@pytest.fixture(scope="module")
def sine_3x() -> tuple:
    """20 s of the QUBE shape driven by a two-sine voltage, pendulum hanging: torque per volt ×3, arm inertia ×1.5,
    Quanser's arm damping; the config's latency."""
    from benchmarks.suite_realistic import simulate

    rig = load_rig("qube_servo2")
    eff = effects_from_assignments(["input_gain.gain=3", f"arm_inertia.J={1.5 * QUBE_J:.4g}", "arm_viscous.Fv=0.0015"])
    return rig, simulate(rig, "qube_servo2", eff, "sine", 20.0, seed=7)


def _arm_model(rig, rec) -> EquationModel:
    o = Options()
    prep = prepare(rec, rig)
    ctx = Context.build(prep, rig, arm_sigma(prep), o.sigma_pend, o.sigma_fine)
    return EquationModel(ctx, ARM, o.thresholds)


def test_gain_and_inertia_off_together_are_calibrated_first(sine_3x) -> None:
    """One effect alone can only mimic a ×3 torque per volt with a ×1.5 inertia (greedily: a ×10 inertia, then a
    spring, Coulomb friction …); calibrated together first, the selection ends at the truth and nothing else."""
    rig, rec = sine_3x
    em = _arm_model(rig, rec)
    _, sel, trace = em.select()
    first = [r for r in trace if r.get("first")]
    assert first and first[0]["accepted"] and first[0]["pair"] == ["input_gain", "arm_viscous", "arm_inertia"]
    assert set(sel.spec.effects) == {"input_gain", "arm_viscous", "arm_inertia"}
    assert sel.params["input_gain"]["gain"] == pytest.approx(3.0, rel=0.03)
    assert sel.params["arm_inertia"]["J"] == pytest.approx(1.5 * QUBE_J, rel=0.05)
    assert sel.params["arm_viscous"]["Fv"] == pytest.approx(0.0015, rel=0.05)


def test_a_profile_at_the_end_of_its_grid_is_no_estimate(sine_3x) -> None:
    """An inertia at ×10 or ×0.1 of the config's, a deadzone as wide as the 80th percentile of the commands, a limit
    clipping 40 % of them: the ends of the grids searched are not admissible; the jointly calibrated inertia (×1.5) and
    a narrow deadzone are."""
    rig, rec = sine_3x
    em = _arm_model(rig, rec)
    base = em.spec0()

    def at(name: str, kind: str, value: float):
        return em.evaluate(base.with_effect(name).with_value(kind, value))

    J, dz, lim = em.grid("inertia"), em.grid("deadzone"), em.grid("limit")
    assert not em.inside(at("arm_inertia", "inertia", J[-1]), "arm_inertia")
    assert not em.inside(at("arm_inertia", "inertia", J[0]), "arm_inertia")
    assert em.inside(at("arm_inertia", "inertia", 0.5 * QUBE_J), "arm_inertia")
    assert not em.inside(at("input_deadzone", "deadzone", dz[-1]), "input_deadzone")
    assert em.inside(at("input_deadzone", "deadzone", dz[3]), "input_deadzone")
    assert not em.inside(at("input_saturation", "limit", lim[0]), "input_saturation")
    assert em.inside(at("input_saturation", "limit", lim[-1]), "input_saturation")
    joint = em._joint(em.evaluate(base), ["input_gain", "arm_viscous", "arm_inertia"])
    assert em.inside(joint, "arm_inertia")
    assert joint.params["arm_inertia"]["J"] == pytest.approx(1.5 * QUBE_J, rel=0.05)


def test_a_balancing_loop_holding_a_constant_torque_calibrates_it_with_the_gain() -> None:
    """Balancing, the loop holds a constant arm torque with a constant command: left out, that torque is read as a
    gain (×0.08 for ×1.5) beside a spring. The inertia of the balancing arm is not identifiable (its profile runs to
    the grid's end), so the calibration without it but with the offset goes first: the speed per volt and the
    torque come back, and no spring or deadzone."""
    from benchmarks.suite_realistic import simulate

    rig = load_rig("qube_servo2")
    true = {"gain": 1.5, "Fv": 0.0015, "tau": 0.0005}
    eff = effects_from_assignments([f"input_gain.gain={true['gain']}", "arm_inertia.J=3.7e-05",
                                    f"arm_viscous.Fv={true['Fv']}", f"arm_bias.tau={true['tau']}"])
    rec = simulate(rig, "qube_servo2", eff, "balance", 15.0, seed=11)
    em = _arm_model(rig, rec)
    _, sel, trace = em.select()
    first = [r for r in trace if r.get("first")]
    assert [r["pair"] for r in first if not r["accepted"]] == [
        ["input_gain", "arm_viscous", "arm_inertia"], ["input_gain", "arm_viscous", "arm_inertia", "arm_bias"],
        ["input_gain", "arm_viscous"]]
    assert first[-1]["accepted"] and first[-1]["pair"] == ["input_gain", "arm_viscous", "arm_bias"]
    assert set(sel.spec.effects) == {"input_gain", "arm_viscous", "arm_bias"}
    a = rig.actuator
    d = a.Kt * a.Ke / a.R

    def speed_per_volt(g: float, fv: float) -> float:
        return g * a.Kt / a.R / (d + fv)

    p = sel.params
    assert speed_per_volt(p["input_gain"]["gain"], p["arm_viscous"]["Fv"]) == pytest.approx(
        speed_per_volt(true["gain"], true["Fv"]), rel=0.02)
    assert p["arm_bias"]["tau"] == pytest.approx(true["tau"], rel=0.2)


def test_one_quantiser() -> None:
    """Nearest level, ties up, the grid shifted by a sub-count phase; the DAQ's counts are the same function's."""
    q = 0.01
    x = np.array([0.0, 0.0049, 0.005, -0.005, 0.0151, -0.0151])
    assert np.allclose(quantise(x, q), [0.0, 0.0, 0.01, 0.0, 0.02, -0.02])
    assert np.allclose(quantise(x, q, 0.25), q * (np.floor(x / q + 0.75) - 0.25))
    assert np.all(np.abs(quantise(x, q, 0.3) - x) <= q / 2 + 1e-15)
    assert np.allclose(quantise(quantise(x, q), q), quantise(x, q))
    cal = Calibration(phi_counts_per_rev=2048)
    phi = 1.2345
    assert cal.to_counts(0.0, 0.0, phi)[2] == int(count_of(phi, 2 * math.pi / 2048)) == round(phi / (2 * math.pi / 2048))
    assert cal.quantize_adc(0.5 * cal.theta_rad_per_count, cal.theta_rad_per_count) == (1, False)  # a tie goes up
