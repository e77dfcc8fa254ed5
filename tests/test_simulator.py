"""Simulator: determinism, LuGre stability, the measurement chain, the actuator chain."""

from __future__ import annotations

import math

import numpy as np
import pytest

from furuta_rt.config import load_rig
from furuta_rt.model.effects import Effects
from furuta_rt.model.rig import RigModel
from furuta_rt.sim.closed_loop import run_closed_loop
from furuta_rt.sim.simulator import Simulator

LUGRE = {"arm_lugre": {"sigma0": 1e4, "sigma1": 20.0, "Fc": 0.1, "Fs": 0.15, "vs": 0.1, "Fv": 0.01}}


def test_seeded_runs_are_identical_and_seeds_differ(thesis_rig) -> None:
    eff = Effects.model_validate({"arm_coulomb": {"Fc": 0.1}})
    a = run_closed_loop(thesis_rig, 2.0, effects=eff, seed=3)
    b = run_closed_loop(thesis_rig, 2.0, effects=eff, seed=3)
    c = run_closed_loop(thesis_rig, 2.0, effects=eff, seed=4)
    assert np.array_equal(a.u, b.u) and np.array_equal(a.theta, b.theta)
    assert not np.array_equal(a.theta, c.theta)


def test_stiff_lugre_balances_without_blowing_up(thesis_rig) -> None:
    rec = run_closed_loop(thesis_rig, 5.0, effects=Effects.model_validate(LUGRE))
    assert np.all(np.isfinite(rec.theta)) and np.max(np.abs(rec.theta[500:])) < 0.1
    # bristle force never exceeds the Stribeck peak by much (no numerical overshoot)
    assert np.max(np.abs(rec.extra["friction"])) < 0.15 * 1.5


def test_measured_theta_is_the_bessel_path_output(thesis_rig) -> None:
    """The simulator's θ_f, θ̇_f equal the Bessel path H(s), s·H(s) applied to the true θ (lsim)."""
    from scipy.signal import lsim

    model = RigModel.from_config(thesis_rig)
    sim = Simulator(model, x0=(math.pi - 0.2, 0.0, 0.0, 0.0))
    t, true, meas, meas_d = [], [], [], []
    for _ in range(1000):
        t.append(sim.t)
        true.append(sim.theta)
        y, yd = sim.filtered_theta()
        meas.append(y)
        meas_d.append(yd)
        sim.advance()
    A, B, _ = model.bessel.state_space()
    _, out, _ = lsim((A, B, np.eye(2), np.zeros((2, 1))), np.array(true), np.array(t), X0=[true[0], 0.0])
    assert np.max(np.abs(out[:, 0] - meas)) < 2e-3 * np.ptp(true)
    assert np.max(np.abs(out[:, 1] - meas_d)) < 2e-3 * np.ptp(meas_d)
    # and it lags: the low-frequency group delay of the path is 1/w = 1.3617/50 s
    assert -np.angle(model.bessel.response(1.0)) == pytest.approx(1.3617 / 50.0, rel=1e-3)


def test_encoder_and_adc_quantisation(thesis_rig) -> None:
    model = RigModel.from_config(thesis_rig)
    sim = Simulator(model, x0=(0.0, 0.0, 0.3, 0.0))
    s = sim.sample()
    assert s.phi_count == round(0.3 / (2 * math.pi / 4096))
    m = sim.measure()
    assert abs(m.phi - 0.3) <= math.pi / 4096


def test_actuator_delay_gain_and_deadzone(thesis_rig) -> None:
    eff = Effects.model_validate({"input_delay": {"delay": 0.01}, "input_gain": {"gain": 0.5}})
    sim = Simulator(RigModel.from_config(thesis_rig, eff), x0=(math.pi, 0.0, 0.0, 0.0))
    sim.set_command(0.2)
    sim.advance(4)  # 8 ms < 10 ms delay: nothing yet
    assert abs(sim.phi_dot) < 1e-12
    sim.advance(10)
    assert sim.phi_dot > 0.0
    dz = Effects.model_validate({"input_deadzone": {"width": 0.3}})
    sim = Simulator(RigModel.from_config(thesis_rig, dz), x0=(math.pi, 0.0, 0.0, 0.0))
    sim.set_command(0.25)
    sim.advance(50)
    assert abs(sim.phi_dot) < 1e-12


def test_dc_motor_torque_and_back_emf() -> None:
    rig = load_rig("macstepien")
    sim = Simulator(RigModel.from_config(rig), x0=(math.pi, 0.0, 0.0, 0.0))
    a = rig.actuator
    p = rig.lumped()
    sim.set_command(2.0)  # volts
    sim.advance(1)
    # from rest the arm accelerates with (Kt V / R)·(M⁻¹)₂₂, (M⁻¹)₂₂ = α/ζ with the pendulum hanging
    assert sim.phi_dot == pytest.approx(a.Kt * 2.0 / a.R * p.alpha / p.zeta * 0.002, rel=1e-3)
    # at the no-load speed V/Ke the motor gives no torque: the arm neither speeds up nor slows down
    # (slow enough, 3.8 rad/s, that the hanging pendulum is not flung out: φ̇² < ε/α)
    volts = 0.005
    sim = Simulator(RigModel.from_config(rig), x0=(math.pi, 0.0, 0.0, volts / a.Ke))
    sim.set_command(volts)
    sim.advance(50)
    assert sim.phi_dot == pytest.approx(volts / a.Ke, rel=1e-9)
