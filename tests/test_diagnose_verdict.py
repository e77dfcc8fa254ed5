"""The verdict per equation (furuta_rt.diagnose.judgement.verdict): a null recording is consistent, a library effect is
explained, a mismatch outside the library (the pendulum's inertia) is neither and names the inertia first; the noise
floor matches the true sensor part of the residual on the simulator."""

from __future__ import annotations

import itertools
from dataclasses import replace

import numpy as np
import pytest

from benchmarks import suite
from furuta_rt.config import load_rig
from furuta_rt.diagnose import Options, diagnose
from furuta_rt.diagnose.judgement import noise
from furuta_rt.diagnose.judgement.locate import Location, describe
from furuta_rt.diagnose.regression.library import ARM, PEND

FAST = Options(closed_loop=False, max_windows=15)
SECONDS = 25.0


@pytest.fixture(scope="module")
def rig():
    return load_rig("thesis")


@pytest.fixture(scope="module")
def runs(rig, tmp_path_factory):
    """Short recordings (25 s) of a null case, a θ-offset case and a pendulum-inertia +20 % case, diagnosed."""
    cache = tmp_path_factory.mktemp("verdict")
    cases = {
        "null": suite.Case("null", (), 3, "sine", duration=SECONDS),
        "offset": suite.Case("theta_offset", ("theta_offset.offset=-0.01",), 20, "sine", duration=SECONDS),
        "inertia": suite.Case("outside Jp +20%", (), 71, "sine", duration=SECONDS, rig_change=(("plant.Jp", 1.2),)),
    }
    out = {}
    for key, case in cases.items():
        rec = suite.generate(case, rig, cache)
        d = diagnose(rec, rig, FAST)
        out[key] = (case, rec, d, d.to_json())
    return out


def test_null_case_is_consistent(runs):
    js = runs["null"][3]
    for eq in (ARM, PEND):
        e = js["equations"][eq]
        assert e["verdict"] == "consistent", (eq, e)
        assert e["unexplained"] is None
        # the residual is at the noise floor (within the floor estimate's accuracy), not merely "no effect found"
        assert e["residual_nominal"] < 1.3 * e["noise_floor"]
    assert js["summary"].startswith("arm equation consistent")
    assert "pendulum equation consistent" in js["summary"]


def test_library_effect_is_explained(runs):
    js = runs["offset"][3]
    e = js["equations"][PEND]
    assert e["verdict"] == "explained", e
    assert e["residual_nominal"] > 10 * e["noise_floor"]  # the offset is far above the floor ...
    assert e["residual_augmented"] < 1.3 * e["noise_floor"]  # ... and with it fitted the residual is at the floor
    assert "pendulum equation explained by theta_offset" in js["summary"]


def test_pendulum_inertia_is_outside_the_library(runs):
    case, _, _, js = runs["inertia"]
    e = js["equations"][PEND]
    assert e["verdict"] in ("partly_explained", "unexplained"), e
    assert js["effects"] == []  # nothing in the library is named for it
    causes = e["unexplained"]["possible_causes"]
    assert causes and causes[0]["key"] == "Jp", causes
    # the config's Jp is 20 % below the truth: the cause's value says so (within its standard error and a margin)
    factor = float(causes[0]["value"].split("=")[1].split("×")[0])
    assert abs(factor - 1.2) < 0.06, causes[0]
    assert "Jp" in js["summary"]
    assert "pendulum equation unexplained" in js["summary"] or "pendulum equation partly explained" in js["summary"]
    score = suite.outside_score(case, js)
    assert score["verdict_right"] and score["cause_right"] and not score["false_effects"]


def test_verdict_keys(runs):
    for _, _, _, js in runs.values():
        assert isinstance(js["summary"], str) and js["summary"]
        assert next(iter(js)) == "summary"
        for e in js["equations"].values():
            assert e["verdict"] in ("consistent", "explained", "partly_explained", "unexplained", "not_assessed")
            for key in ("residual_nominal", "residual_augmented", "noise_floor", "unexplained"):
                assert key in e


def test_noise_floor_matches_the_true_sensor_part(runs, rig):
    """On the simulator the true states are known: the residual computed from them is (almost) zero, so the nominal
    residual of a null case is all sensor noise. The Monte Carlo floor must match it within its stated accuracy."""
    _, rec, d, _ = runs["null"]
    ctx = d.context
    true = replace(ctx.prep, theta_f=rec.extra["true_theta"], theta_dot_f=None, phi=rec.extra["true_phi"], bessel=None)
    for eq in (ARM, PEND):
        rows = d.models[eq].row_mask
        sigma = ctx.states(eq).filt.sigma
        sensor = noise._residual(ctx, eq, ctx.states(eq)) - noise._residual(ctx, eq, true.states(sigma))
        floor = noise.draws(ctx, eq)
        ratio = float(np.sqrt(np.mean(floor[:, rows] ** 2) / np.mean(sensor[rows] ** 2)))
        assert 1 / 1.3 < ratio < 1.3, (eq, ratio)


def test_describe_never_says_consistent_without_the_verdict():
    loc = Location(PEND, 0.165, {"θ̈": 0.9, "1": 0.0}, {}, [])
    assert "consistent" not in describe(loc, [])
    assert "consistent" not in describe(loc, [], "unexplained")
    assert "consistent" in describe(loc, [], "consistent")


def test_a_transient_far_above_the_floor_is_never_within_it():
    """An excess concentrated in one block (a step's transient) has a small block t and fails the sign test; the
    size guard still refuses it, and a residual that is the floor's own size stays within."""
    from furuta_rt.diagnose.judgement.verdict import FLOOR_ACCURACY, N_BLOCKS, SIZE_MAX, T_CRIT, block_t

    rng = np.random.default_rng(0)
    n = 16 * 200
    floor = rng.standard_normal((4, n))
    same = rng.standard_normal(n)
    assert block_t(same, floor) <= T_CRIT
    transient = same.copy()
    transient[: n // N_BLOCKS] *= 12.0  # rms ≈ 3× the floor's, all in the first block
    edges = np.linspace(0, n, N_BLOCKS + 1).round().astype(int)
    d = np.array([np.mean(transient[a:b] ** 2) - FLOOR_ACCURACY**2 * np.mean(floor[:, a:b] ** 2)
                  for a, b in itertools.pairwise(edges)])
    assert np.mean(d) / (np.std(d, ddof=1) / np.sqrt(N_BLOCKS)) <= T_CRIT  # the t test alone would pass it
    assert np.sqrt(np.mean(transient**2)) > SIZE_MAX * FLOOR_ACCURACY
    assert block_t(transient, floor) == np.inf
