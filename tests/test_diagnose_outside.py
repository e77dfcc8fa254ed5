"""Mismatches outside the library (issue 13): a compliant rotor–arm coupling is not explained by library effects that
stand in for it (the band test, furuta_rt.diagnose.stages.gate.band_check) and is offered as a compliance or mode; a true
library effect passes the band test; a pendulum-inertia error seen only in the catch transient of a balancing run is
not `consistent` (the possible causes' blocked standard error and their share removed where they act)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from benchmarks import suite
from furuta_rt.config import load_rig
from furuta_rt.diagnose import Options, diagnose
from furuta_rt.diagnose.judgement import verify
from furuta_rt.diagnose.judgement.verdict import (
    FLOOR_ACCURACY,
    T_CRIT,
    _block_se,
    _removes_where_it_acts,
    band_t,
    block_t,
    mode_cause,
)
from furuta_rt.diagnose.regression.library import ARM, PEND
from furuta_rt.diagnose.stages import gate
from furuta_rt.diagnose.stages.findings import refit

FAST = Options(closed_loop=False, max_windows=20)
SECONDS = 30.0


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Recordings of the compliant coupling (60 s: in 30 s its remainder is the catch transient's, one time block that
    the block test does not see — a known weakness), a true input gain and Jp + 20 % without reference (30 s)."""
    rig, cache = load_rig("thesis"), tmp_path_factory.mktemp("outside")
    coupling = (("coupling.rotor_inertia", 0.001), ("coupling.stiffness", 2.5), ("coupling.damping", 0.005))
    cases = {"coupling": suite.Case("outside compliant arm coupling", (), 77, "sine", 2 * SECONDS, coupling),
             "gain": suite.Case("input_gain", ("input_gain.gain=0.8",), 25, "sine", SECONDS),
             "inertia": suite.Case("outside Jp +20% (no reference)", (), 76, None, SECONDS, (("plant.Jp", 1.2),))}
    diagnoses = {k: diagnose(suite.generate(c, rig, cache), rig, FAST) for k, c in cases.items()}
    return {k: (cases[k], d, d.to_json()) for k, d in diagnoses.items()}


def test_compliant_coupling_names_at_most_the_rotor_inertia(runs):
    """Below the coupling's 8 Hz mode the rotor (2 % of the arm's inertia) turns with the arm: the selection may name
    that inertia (an arm inertia of J + Jr, or its look-alike, a gain of J / (J + Jr) ≈ 0.98) and nothing else. The
    arm residual is well above its floor (a 10–80× low-frequency excess of the floor's spectrum); an effect moved out
    for not predicting better did not predict better. (Generated afresh, the recording leaves the arm `explained` once
    the inertia is in: the mode's remaining band excess, 3.6× the floor's at 0.5–1 Hz, has t = 4.65 against the
    per-band test's 4.85 — the size tests do not see the mode beyond the inertia; its signature does, below.)"""
    case, _, js = runs["coupling"]
    assert all(suite.rotor_inertia_seen(case, e) for e in js["effects"]), js["effects"]
    arm = js["equations"][ARM]
    assert arm["verdict"] != "consistent", arm
    assert arm["residual_nominal"] > 1.5 * arm["noise_floor"]
    band = arm["test"]["band_nominal"]
    assert band["power_ratio"] > 10 and band["band_hz"][1] <= 4.0, band  # a low-frequency excess
    for m in js["not_predictive"]:
        assert "band" in m or m["prediction"]["paired_t"] > -verify.T_DIFFERENT, m
    assert not suite.outside_score(case, js)["false_effects"]


def test_compliant_coupling_is_not_explained_its_signature_is_named(runs):
    """After the rotor inertia the arm's remainder follows the compliance's own column, −τ̈_command (the rotor turns by
    τ_c/k more than the arm), with J_m/k = 0.001/2.5 = 4·10⁻⁴ s² (its mode with the arm held at 8.0 Hz): the arm is
    `partly_explained`, that compliance its first possible cause. A true input gain (no spring) is `explained`."""
    case, _, js = runs["coupling"]
    arm = js["equations"][ARM]
    assert arm["verdict"] in ("partly_explained", "unexplained"), arm
    first = arm["unexplained"]["possible_causes"][0]
    assert first["key"] == "compliance" and first["coefficient"] > 4 * first["se"], first
    assert 0.5 < first["coefficient"] / (0.001 / 2.5) < 2.0, first
    assert suite.outside_score(case, js)["verdict_right"]
    assert runs["gain"][2]["equations"][ARM]["verdict"] == "explained"


def test_the_band_test_moves_stand_ins_for_the_coupling(runs):
    """On the coupling recording, a gain, a saturation and an inertia fitted together (what the selection took
    before the look-alike scoring changed) give a gain that doubles when the kernel is twice as wide: moved out by
    the band test, and a `mode` cause is offered for it."""
    _, d, _ = runs["coupling"]
    em = d.models[ARM]
    spec = em.spec0()
    for name in ("input_gain", "input_saturation", "arm_inertia"):
        spec = spec.with_effect(name)
    res = {ARM: SimpleNamespace(selected=refit(em, spec))}
    names = [(ARM, n) for n in ("input_gain", "input_saturation", "arm_inertia")]
    bad = gate.band_check(d.context, {ARM: em}, res, names, FAST)
    assert "input_gain" in bad, bad
    b = bad["input_gain"]
    assert b["sigma_wide"] == pytest.approx(2 * b["sigma"], rel=0.05)
    assert abs(b["value_wide"] - b["value"]) > gate.BAND_SHARE * min(abs(b["value"] - 1.0), abs(b["value"]))
    cause = mode_cause(ARM, [{"name": "input_gain", "equation": ARM, "band": b}])
    assert cause is not None and cause["key"] == "mode" and "input_gain" in cause["value"]
    assert mode_cause(ARM, []) is None


def test_a_library_effect_passes_the_band_test(runs):
    """A true input gain of 0.8 (or its look-alike, the arm inertia) has the same value in both bands."""
    _, d, js = runs["gain"]
    names = [e["name"] for e in js["effects"]]
    assert names and set(names) <= {"input_gain", "arm_inertia"}, names
    assert not any("band" in m for m in js["not_predictive"])
    res, ems = d.equations, d.models
    assert gate.band_check(d.context, ems, res, [(ARM, n) for n in names], FAST) == {}
    assert js["equations"][ARM]["verdict"] == "explained"


def test_inertia_seen_only_in_the_catch_transient_is_not_consistent(runs):
    case, _, js = runs["inertia"]
    pend = js["equations"][PEND]
    assert pend["verdict"] in ("partly_explained", "unexplained"), pend
    assert js["effects"] == []
    causes = pend["unexplained"]["possible_causes"]
    keys = [c["key"] for c in causes if c is causes[0] or c["indistinguishable_from_first"]]
    assert "Jp" in keys, causes  # among the look-alikes the recording cannot tell apart
    jp = next(c for c in causes if c["key"] == "Jp")
    assert abs(jp["coefficient"] + 0.2) < 0.06, jp  # config Jp = true/1.2: the fit says ≈ 1.2 × config
    assert suite.outside_score(case, js)["verdict_right"]


def test_block_se_is_not_blown_up_by_one_dominant_block():
    """One block holds 97 % of a column's weight and measures a = −0.19; fifteen quiet blocks follow another
    quantity (+0.4). The delete-one jackknife of the ratio swings to the quiet blocks' value when the strong block is
    left out (se ≈ 0.6); the linearised one weighs each block by its share (se ≈ 0.02)."""
    sxx = np.r_[1.1e-4, np.full(15, 2.5e-7)]
    coef = np.r_[-0.19, np.full(15, 0.4)]
    rng = np.random.default_rng(1)
    sxy = coef * sxx * (1 + 0.01 * rng.standard_normal(16))
    a = sxy.sum() / sxx.sum()
    folds = np.array([(sxy.sum() - sxy[k]) / (sxx.sum() - sxx[k]) for k in range(16)])
    delete_one = np.sqrt(15 / 16 * np.sum((folds - folds.mean()) ** 2))
    assert delete_one > 0.5
    assert _block_se(sxy, sxx, a) < 0.03
    assert abs(a) / _block_se(sxy, sxx, a) > 4


def test_block_se_matches_the_jackknife_on_even_blocks():
    rng = np.random.default_rng(2)
    sxx = rng.uniform(0.9, 1.1, 16)
    sxy = 0.3 * sxx + 0.05 * rng.standard_normal(16)
    a = sxy.sum() / sxx.sum()
    folds = np.array([(sxy.sum() - sxy[k]) / (sxx.sum() - sxx[k]) for k in range(16)])
    delete_one = np.sqrt(15 / 16 * np.sum((folds - folds.mean()) ** 2))
    assert _block_se(sxy, sxx, a) == pytest.approx(delete_one, rel=0.1)


def test_share_removed_where_a_cause_acts():
    """A cause removing 60 % of the residual in the one block it acts in removes 60 % where it acts, though only
    a few percent of the whole."""
    sxx = np.r_[100.0, np.full(15, 0.01)]
    syy = np.r_[100.0 / 0.6 * 0.04, np.full(15, 10.0)]  # a = 0.2: a²·sxx = 4 = 60 % of block 0's 6.67
    local = _removes_where_it_acts(0.2, sxx, syy)
    assert local == pytest.approx(0.6, abs=0.01)
    assert 0.2**2 * sxx.sum() / syy.sum() < 0.03


def test_band_test_sees_a_low_frequency_excess_the_block_test_misses():
    """A 0.7 Hz torque of 1/4 of the floor's rms: the time-block test (its power is 6 % of the floor's, within K²)
    passes it; in its own octave the floor, which grows with frequency, is far below it. A residual that is a fresh
    draw of the floor passes both."""
    rng = np.random.default_rng(3)
    dt, n = 0.002, 30000
    t = np.arange(n) * dt
    kernel = np.exp(-0.5 * (np.arange(-100, 101) * dt / 0.02) ** 2)
    hp = np.array([1.0, -2.0, 1.0])  # a second difference: the floor's power grows with frequency, as through θ̈

    def noise_draw() -> np.ndarray:
        return np.convolve(np.convolve(rng.standard_normal(n), hp, "same"), kernel / kernel.sum(), "same")

    floor = np.array([noise_draw() for _ in range(4)])
    rows = np.ones(n, dtype=bool)
    same = noise_draw()
    assert block_t(same, floor) <= T_CRIT
    assert band_t(same, floor, rows, dt, 0.04)[0] <= 1.0
    slow = same + 0.25 * np.std(floor) * np.sqrt(2) * np.sin(2 * np.pi * 0.7 * t)
    assert np.mean(slow**2) < FLOOR_ACCURACY**2 * np.mean(floor**2)
    assert block_t(slow, floor) <= T_CRIT
    score, where = band_t(slow, floor, rows, dt, 0.04)
    assert score > 1.0 and where["band_hz"][0] <= 0.7 < where["band_hz"][1], where


def test_consistent_says_what_the_recording_could_have_seen(runs):
    """A `consistent` pendulum equation of a sine-excited run states the smallest pendulum-inertia change it could
    have seen: below the 20 % that the outside group's Jp case has (which it does see), above zero."""
    _, _, js = runs["gain"]
    pend = js["equations"][PEND]
    assert pend["verdict"] == "consistent", pend
    change = pend["detectable_change"]
    assert 0.0 < change["Jp"] < 0.2, change
    assert "theta_scale" in change and "theta_sign" not in change
