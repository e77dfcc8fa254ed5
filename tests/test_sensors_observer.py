"""Measurement path (section 3.3, appendix B) and the φ̇ observer."""

from __future__ import annotations

import math

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter

from furuta_rt.controller.controller import Controller, Measurement, observer_design
from furuta_rt.model.effects import Effects
from furuta_rt.model.sensors import BesselPath, Calibration
from furuta_rt.sim.closed_loop import run_closed_loop


def test_bessel_cutoff_is_minus_3db() -> None:
    b = BesselPath(50.0)
    assert abs(b.response(50.0)) == pytest.approx(1 / math.sqrt(2), rel=2e-4)
    assert abs(b.response(0.0)) == pytest.approx(1.0)


@pytest.mark.parametrize("omega", [1.0, 10.0, 50.0, 200.0])
def test_bessel_gain_and_phase_match_formula(omega: float) -> None:
    b = BesselPath(50.0)
    w = 50.0 / 1.3617
    H = 3 * w**2 / ((1j * omega) ** 2 + 3 * w * 1j * omega + 3 * w**2)
    assert b.response(omega) == pytest.approx(H, rel=1e-12)
    # Bessel: nearly linear phase, group delay at low frequency = a1/a0 = 1/w
    if omega <= 10.0:
        assert -np.angle(b.response(omega)) / omega == pytest.approx(1 / w, rel=0.02)


def test_bessel_state_space_agrees_with_transfer_function() -> None:
    b = BesselPath(50.0)
    A, B, _ = b.state_space()
    for omega in (3.0, 30.0, 300.0):
        x = np.linalg.solve(1j * omega * np.eye(2) - A, B).ravel()
        assert x[0] == pytest.approx(b.response(omega), rel=1e-12)
        assert x[1] == pytest.approx(1j * omega * b.response(omega), rel=1e-12)  # θ̇ channel = s·H(s)


def test_calibration_round_trip() -> None:
    cal = Calibration(theta_offset_counts=12)
    for th, thd, ph in [(0.1, -2.0, 1.5), (-0.4, 10.0, -20.0)]:
        a, b, c, over = cal.to_counts(th, thd, ph)
        assert not over
        t2, td2, p2 = cal.to_si(a, b, c)
        assert t2 == pytest.approx(th, abs=cal.theta_rad_per_count)
        assert td2 == pytest.approx(thd, abs=cal.theta_dot_rad_s_per_count)
        assert p2 == pytest.approx(ph, abs=cal.phi_rad_per_count)
    assert cal.to_counts(10.0, 0.0, 0.0)[3]  # overrange flagged


def test_steady_state_gain_is_what_filterpy_converges_to(thesis_rig) -> None:
    d = observer_design(thesis_rig)
    kf = KalmanFilter(dim_x=2, dim_z=1, dim_u=2)
    kf.F, kf.B, kf.H, kf.Q, kf.R = d.Ad, d.Bd, d.C, d.Q, np.array([[d.R]])
    kf.P *= 1.0
    for _ in range(5000):
        kf.predict(u=np.zeros(2))
        kf.update(np.array([0.0]))
    np.testing.assert_allclose(kf.K.ravel(), d.K, rtol=1e-6)


def test_observer_tracks_arm_velocity_in_closed_loop(thesis_rig) -> None:
    # arm Coulomb friction keeps the loop in a limit cycle: the arm moves and reverses all the time
    friction = Effects.model_validate({"arm_coulomb": {"Fc": 0.3}})
    rec = run_closed_loop(thesis_rig, 6.0, effects=friction, x0=(0.05, 0.0, 0.0, 0.0))
    err = rec.extra["phi_dot_hat"][1000:] - rec.extra["true_phi_dot"][1000:]
    scale = np.std(rec.extra["true_phi_dot"][1000:])
    assert scale > 0.1
    assert np.sqrt(np.mean(err**2)) < 0.15 * scale


def test_controller_is_deterministic_and_saturates(thesis_rig) -> None:
    a = Controller.from_rig(thesis_rig)
    b = Controller.from_rig(thesis_rig)
    for k in range(100):
        m = Measurement(k * 0.002, 0.01 * math.sin(k / 7), 0.05, 0.1, )
        assert a.update(m) == b.update(m)
    out = a.update(Measurement(1.0, 1.0, 0.0, 0.0))  # 19.9 N m wanted
    assert out.saturated and out.u == thesis_rig.actuator.limit
