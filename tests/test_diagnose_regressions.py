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
