"""Regressions of `diagnose` found on the realistic group (each failed before its fix)."""

from __future__ import annotations

from furuta_rt.config import load_rig
from furuta_rt.diagnose import Options, diagnose, suite
from furuta_rt.diagnose.library import CANDIDATES
from furuta_rt.diagnose.select import Spec
from furuta_rt.model.effects import EFFECT_TYPES


def test_removing_an_effect_removes_what_requires_it() -> None:
    """arm_lugre is a Stribeck peak on arm_coulomb's sliding level: a model without the level has no peak either."""
    assert CANDIDATES["arm_lugre"].requires == "arm_coulomb"
    spec = Spec("arm", ("arm_coulomb", "input_gain", "arm_lugre"), vs=0.3)
    out = spec.without("arm_coulomb")
    assert out.effects == ("input_gain",) and out.vs == 0.0
    assert spec.without("arm_lugre").effects == ("arm_coulomb", "input_gain")


def test_qube_sine_seed_101_is_diagnosed_with_physical_effects(tmp_path) -> None:
    """QUBE sine (gain ×3, heavier arm, damping): the forward steps took arm_lugre (with arm_coulomb) and arm_spring,
    the backward pass then dropped arm_coulomb and left a negative Stribeck peak and a negative spring, clipped to
    Fc = Fs = 0 and k = 0 — a LuGre law with g(v) = 0 that raised ZeroDivisionError in the peak-window stage."""
    case = next(c for c in suite.realistic_cases() if c.seed == 101)
    rec = suite.generate_realistic(case, tmp_path)
    out = diagnose(rec, load_rig(case.shape), Options(closed_loop=False)).to_json()
    names = {e["name"] for e in out["effects"]}
    assert "input_gain" in names and not {"arm_lugre", "arm_spring"} & names, names
    for e in out["effects"]:  # every effect reported is an effect of the vocabulary with a non-zero size
        EFFECT_TYPES[e["name"]].model_validate(e["params"])
        assert any(v != 0 for v in e["params"].values()), e


def test_single_step_from_rest_is_a_gain_not_a_bias(tmp_path) -> None:
    """macstepien-shaped: 1 s at rest, then one voltage step held (true torque per volt ×7, no bias). On the step the
    gain's extra torque and a constant torque are the same column; the rest before it is not: a bias of the size the
    step needs would have turned the frictionless arm by many radians there. Reported before: arm_bias 0.151 N m and
    the speed per volt 43 % low."""
    case = next(c for c in suite.realistic_cases() if c.seed == 111)
    rec = suite.generate_realistic(case, tmp_path)
    out = diagnose(rec, load_rig(case.shape), Options(closed_loop=False)).to_json()
    found = {e["name"]: e["params"] for e in out["effects"]}
    assert "arm_bias" not in found and abs(found["input_gain"]["gain"] / 7.0 - 1.0) < 0.02, found
    told = [a for a in out["lookalikes"] if set(a["effects"]) == {"input_gain", "arm_bias"}]
    assert told and told[0]["reported"] == "input_gain" and told[0]["rest"]["turn_rad"] > 1.0, told
    s = suite.score_realistic(case, out, 0.0)
    assert s.detected["speed_per_volt"], s.errors


def test_a_bias_the_config_already_has_is_no_departure() -> None:
    """The rig's own arm_bias is part of the nominal model (Context.arm_known_friction): a recording with exactly that
    constant torque has nothing left to report; with twice it, the departure is the second half (the reported value
    is the total, as for every effect)."""
    from furuta_rt.model.effects import Effects
    from furuta_rt.sim.closed_loop import run_closed_loop

    rig = load_rig("thesis")
    configured = rig.model_copy(update={"effects": Effects.model_validate({"arm_bias": {"tau": 0.05}})})
    ref = suite.reference_signal("sine", 6000, 500.0, 4)
    for true, expect in ((0.05, None), (0.10, 0.10)):
        rec = run_closed_loop(rig, 12.0, effects=Effects.model_validate({"arm_bias": {"tau": true}}), seed=4, reference=ref)
        d = diagnose(rec, configured, Options(closed_loop=False)).to_json()
        found = {e["name"]: e["params"] for e in d["effects"]}
        if expect is None:
            assert "arm_bias" not in found, found
        else:
            assert abs(found["arm_bias"]["tau"] - expect) < 0.1 * expect, found
