"""The designed-experiment benchmark's independent simulator (benchmarks.suite_independent_experiments): it runs the
plans as the daemon does — open loop from hanging, or balancing about the plan's reference with its torque added —
and each suite truth has an independent version."""

from __future__ import annotations

import math

import numpy as np
import pytest

from benchmarks import suite_independent_experiments as ind
from furuta_rt.config import load_rig
from furuta_rt.experiment import hanging
from furuta_rt.experiment.plan import Plan, Segment


def test_every_suite_truth_has_an_independent_version() -> None:
    for case in ind.CASES:
        for effects in (case.a, case.b):
            ind.Truth.from_effects(effects)
    assert ind.Truth.from_effects({"input_gain": {"gain": 0.8}}).arm_torque(1.0, 0.0, 0.0) == pytest.approx(0.8)
    dz = ind.Truth.from_effects({"input_deadzone": {"width": 0.02}})
    assert dz.arm_torque(0.015, 0.0, 0.0) == 0.0 and dz.arm_torque(-0.05, 0.0, 0.0) == pytest.approx(-0.03)
    spring = ind.Truth.from_effects({"arm_spring": {"k": 0.05, "phi0": 0.1}})
    assert spring.arm_torque(0.0, 0.3, 0.0) == pytest.approx(-0.01)


def test_hanging_plan_open_loop_agrees_with_our_simulator_on_the_nominal_rig() -> None:
    """Same thesis plant, independent integration and sensor path: a resonant 6 s chirp swings the pendulum and drives
    the arm alike (peaks within 2 %); θ is read modulo 2π as the rig's full-turn sensor; a gain of 0.8 swings less."""
    rig = load_rig("thesis")
    plan = hanging.candidate_plans(rig, 6.0, settle_s=0.5)[6]
    ours = hanging.simulate(rig, {}, plan, 0, substep_hz=2000.0, noise=False)
    theirs = ind.simulate(ind.Truth(), 0.0, 1, plan)
    assert len(theirs.t) == len(ours.t) and np.all(np.abs(theirs.theta) <= math.pi)
    assert np.all(theirs.u[: round(0.5 * 500)] == 0.0) and np.array_equal(theirs.u, ours.u)
    assert hanging.swing(theirs.theta) == pytest.approx(hanging.swing(ours.theta), rel=0.02)
    assert hanging.swing(theirs.theta) > 0.05
    assert np.abs(theirs.phi).max() == pytest.approx(np.abs(ours.phi).max(), rel=0.02)
    weak = ind.simulate(ind.Truth(gain=0.8), 0.0, 1, plan)
    assert hanging.swing(weak.theta) < 0.9 * hanging.swing(theirs.theta)


def test_balancing_plan_moves_the_independent_arm_to_its_reference() -> None:
    """The independent LQR balances about the plan's step (the arm settles near 0.3 rad) and follows the return ramp
    back (the recording ends as the reference reaches 0, the arm a little behind it)."""
    plan = Plan((Segment("step", 3.0, {"phi": 0.3}),), settle_s=1.0, return_speed=0.5)
    rec = ind.simulate(ind.Truth(), 0.0, 2, plan)
    step_end = slice(500 + 1400, 500 + 1500)
    assert np.mean(rec.phi[step_end]) == pytest.approx(0.3, abs=0.03)
    assert np.abs(rec.theta).max() < 0.1 and abs(rec.phi[-1]) < 0.15 and len(rec.t) == 500 + 1500 + 300
