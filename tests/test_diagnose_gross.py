"""Gross datasheet errors and degenerate excitation (issues 13/14): a torque per volt ×50 or ×0.1 found as input_gain
with its value, what a single step pins reported as a combination, no statistic from a kink the commands never
straddle or from a profile that runs to the edge of its range."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.suite_realistic import simulate, true_steady_speed_per_volt
from furuta_rt.config import load_rig
from furuta_rt.diagnose import Options, diagnose
from furuta_rt.diagnose.regression.library import CANDIDATES, kink_supported
from furuta_rt.model.effects import effects_from_assignments

FAST = Options(closed_loop=False, max_windows=15)
B1 = 0.0117  # the macstepien authors' fitted arm damping, N m s/rad


def _diagnosed(excitation: str, gain: float, seconds: float, seed: int):
    rig = load_rig("macstepien")
    effects = effects_from_assignments([f"input_gain.gain={gain}", f"arm_viscous.Fv={B1}"])
    rec = simulate(rig, "macstepien", effects, excitation, seconds, seed)
    return rec, diagnose(rec, rig, FAST), true_steady_speed_per_volt(rig, effects)


def _significant_or_combined(d) -> None:
    """Every effect found by the regression is significant by the selection's rule, or a member of a pinned
    combination; none has an infinite or degenerate t."""
    for e in d.effects:
        assert np.isfinite(e.t), e
        if e.source == "inverse dynamics":
            assert e.t >= 4.0 or (e.cv_gain >= 0.05 and e.t >= 2.0) or (not e.pinned and e.combinations), e


@pytest.mark.parametrize(("gain", "excitation", "seconds", "seed"),
                         [(50.0, "step", 20.0, 7), (0.1, "step", 20.0, 9), (1000.0, "single_step", 6.0, 13)])
def test_a_torque_per_volt_far_off_the_datasheet_is_found_as_the_input_gain(gain: float, excitation: str, seconds: float,
                                                                           seed: int) -> None:
    """Steps of several levels (both signs) with the torque per volt ×50 or ×0.1 the config's, or one step with ×1000
    (a command in the wrong unit): input_gain comes back
    within 10 % (the plausible range used to stop at ×20), with the damping, and the identification reports the same
    values as the effects (one source of truth)."""
    _, d, _ = _diagnosed(excitation, gain, seconds, seed)
    found = {e.name: e for e in d.effects}
    assert set(found) == {"input_gain", "arm_viscous"}, found
    assert found["input_gain"].params["gain"] == pytest.approx(gain, rel=0.1)
    assert found["arm_viscous"].params["Fv"] == pytest.approx(B1, rel=0.1)
    par = d.identification["parameters"]
    assert par["input_gain"]["selected"] and par["input_gain"]["value"] == found["input_gain"].params["gain"]
    assert par["arm_viscous"]["value"] == found["arm_viscous"].params["Fv"]
    assert not par["arm_inertia"]["selected"]  # the config's inertia is the true one: not reported as found
    _significant_or_combined(d)
    assert d.fit["augmented"] < 0.2 * d.fit["nominal"]


def test_one_step_reports_no_saturation_and_the_speed_per_volt_it_pins() -> None:
    """One step from rest to one level (a two-level command) with the torque per volt ×50: no input_saturation or
    input_deadzone (their kinks have commands on one side only: at that level, a kink is a gain), the gain within
    10 %, and the steady speed per volt the data pins — reported by the effects when they cannot pin the gain alone —
    within 1 % of the true one."""
    rec, d, spv = _diagnosed("single_step", 50.0, 6.0, 8)
    assert len(np.unique(rec.u)) == 2
    names = {e.name for e in d.effects}
    assert not names & {"input_saturation", "input_deadzone"}, names
    gain = next(e for e in d.effects if e.name == "input_gain")
    assert gain.params["gain"] == pytest.approx(50.0, rel=0.1)
    combos = d.identification["combinations"]
    assert combos["speed_per_volt"]["value"] == pytest.approx(spv, rel=0.01)
    assert 0 < combos["speed_per_volt"]["se"] < 0.01 * spv
    _significant_or_combined(d)
    evidence = d.to_json()["evidence"]
    assert all(np.isfinite(e["t"]) for e in evidence)


def test_a_kink_needs_commands_on_both_sides() -> None:
    two_level = np.r_[np.zeros(500), np.full(2000, 0.575)]
    assert not kink_supported(two_level, 0.575)  # the saturation at the only level the command takes
    assert not kink_supported(two_level, 0.3)  # a deadzone or saturation below it: nothing between 0 and the kink
    sine = 0.6 * np.sin(np.linspace(0, 20 * np.pi, 5000))
    assert kink_supported(sine, 0.5) and kink_supported(sine, 0.05)
    assert not kink_supported(sine, 0.7)  # no command above it


def test_input_gain_is_plausible_from_a_hundredth_to_a_thousand_times_the_config() -> None:
    rig = load_rig("macstepien")
    plausible = CANDIDATES["input_gain"].plausible
    assert plausible({"gain": 0.01}, rig) and plausible({"gain": 70.0}, rig) and plausible({"gain": 1000.0}, rig)
    assert not plausible({"gain": 0.0}, rig) and not plausible({"gain": -3.0}, rig)


def test_the_page_says_which_effects_only_a_combination_pins() -> None:
    from furuta_rt.diagnose.report.page import html_page

    combo = {"name": "speed_per_volt", "value": 37.83, "se": 0.004, "unit": "rad/s per V",
             "members": ["input_gain", "arm_viscous"]}
    data = {"rig": "r", "effects": [{"name": "input_gain", "params": {"gain": 70.1}},
                                    {"name": "arm_bias", "params": {"tau": 0.01}}],
            "evidence": [{"name": "input_gain", "equation": "arm", "t": 17.0, "se": {"gain": 4.0}, "pinned": False,
                          "pinned_combinations": [combo]},
                         {"name": "arm_bias", "equation": "arm", "t": 9.0, "se": {"tau": 0.001}, "pinned": True,
                          "pinned_combinations": []}],
            "equations": {"arm": {"rows": 1000, "verdict": "partly_explained"}}}
    page = html_page(data, [], [])
    assert page.count("not pinned alone") == 1 and "speed_per_volt = 37.83 ± 0.004 rad/s per V" in page
