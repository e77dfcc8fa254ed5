"""Energy swing-up (Åström & Furuta 2000) inside Controller.update, against the simulator (faster than real time).

The figures asserted here are the simulation's, at the rigs' derived defaults (furuta_rt/controller/swingup.py):
from hanging at rest the thesis rig with arm Coulomb friction 0.3 N m is caught and balancing after 5.4–5.5 s,
the QUBE-Servo 2 after 2.0–2.1 s, the macstepien rig after 1.2–1.3 s, the arm within 2.1 / 1.2 / 3.8 rad of its
start (limits 18.85 / 3.0 / 6.3 rad). The HIL tests (test_swingup_hil.py) use these to bound the real-time runs.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from furuta_rt.config import RigConfig, load_rig
from furuta_rt.controller.controller import Controller
from furuta_rt.controller.swingup import SwingUp, SwingUpDesign, wrap_angle
from furuta_rt.model.effects import effects_from_assignments
from furuta_rt.model.sensors import Measurement
from furuta_rt.sim.closed_loop import run_closed_loop

RIG_EFFECTS = {"thesis": ["arm_coulomb.Fc=0.3"], "qube_servo2": [], "macstepien": []}


def swing_rig(name: str, **swing_up: object) -> RigConfig:
    rig = load_rig(name)
    return rig.model_copy(update={"swing_up": rig.swing_up.model_copy(update={"enabled": True, **swing_up})})


def time_to_upright(t: np.ndarray, theta: np.ndarray, rate_hz: float, window_s: float = 1.0) -> float | None:
    """First time after which |θ| stays below 0.3 rad for ``window_s`` (None: never)."""
    up = np.abs((theta + np.pi) % (2 * np.pi) - np.pi) < 0.3
    n = round(window_s * rate_hz)
    run = np.convolve(up.astype(int), np.ones(n, dtype=int), mode="valid")
    hits = np.flatnonzero(run == n)
    return float(t[hits[0]]) if hits.size else None


@pytest.mark.parametrize("name", list(RIG_EFFECTS))
def test_swing_up_from_hanging_catches_and_balances_within_the_limits(name: str) -> None:
    rig = swing_rig(name)
    effects = effects_from_assignments(RIG_EFFECTS[name]) if RIG_EFFECTS[name] else None
    rec = run_closed_loop(rig, 8.0, effects=effects, x0=(math.pi, 0.0, 0.0, 0.0), seed=1, substep_hz=5000)
    t_up = time_to_upright(rec.t, rec.theta, rig.control.rate_hz)
    expected = {"thesis": 5.5, "qube_servo2": 2.1, "macstepien": 1.3}[name]
    assert t_up is not None and t_up <= expected, t_up
    assert np.max(np.abs(rec.phi)) < 0.7 * rig.safety.phi_limit
    assert np.max(np.abs(rec.u)) <= rig.actuator.limit
    # balancing at the end: the arm brought back towards 0 from where it was caught
    tail = rec.t > rec.t[-1] - 1.0
    assert np.max(np.abs(wrap_angle_array(rec.theta[tail]))) < 0.05
    assert abs(rec.phi[-1]) < 0.5


def wrap_angle_array(x: np.ndarray) -> np.ndarray:
    return (x + np.pi) % (2 * np.pi) - np.pi


def test_without_the_swing_up_the_hanging_pendulum_stays_down() -> None:
    """The same run with the swing-up off: balancing gains from hanging saturate and never bring it up."""
    rig = load_rig("thesis")
    rec = run_closed_loop(rig, 3.0, x0=(math.pi, 0.0, 0.0, 0.0), seed=1, substep_hz=5000)
    assert time_to_upright(rec.t, rec.theta, rig.control.rate_hz) is None


def test_energy_is_zero_upright_and_minus_two_epsilon_hanging() -> None:
    rig = swing_rig("thesis")
    su = SwingUp(SwingUpDesign.from_rig(rig))
    eps = rig.lumped().epsilon
    assert su.energy(0.0, 0.0) == pytest.approx(0.0, abs=1e-15)
    assert su.energy(math.pi, 0.0) == pytest.approx(-2 * eps)
    alpha = rig.lumped().alpha
    assert su.energy(math.pi, 2.0) == pytest.approx(-2 * eps + 0.5 * alpha * 4.0)


def test_pump_adds_energy_below_the_target_and_removes_it_above() -> None:
    """dE/dt = −γ cos θ θ̇ φ̈ (eq. 4): the commanded arm acceleration has the sign that moves E to its target."""
    rig = swing_rig("thesis", arm_omega=1e-9, arm_damping=1e-9)
    su = SwingUp(SwingUpDesign.from_rig(rig))
    p = rig.lumped()
    for theta, theta_dot in ((math.pi - 0.5, 2.0), (math.pi + 0.3, -1.0), (1.0, 3.0), (-2.0, -4.0), (0.5, 12.0)):
        accel = su.arm_acceleration(theta, theta_dot, 0.0, 0.0)
        de_dt = -p.gamma * math.cos(theta) * theta_dot * accel
        e = su.energy(theta, theta_dot) - su.design.energy_target
        assert de_dt * e < 0, (theta, theta_dot, accel, e)


def test_swing_up_torque_gives_the_commanded_arm_acceleration_through_eq_4() -> None:
    rig = swing_rig("thesis")
    su = SwingUp(SwingUpDesign.from_rig(rig))
    plant = su.design.plant
    theta, theta_dot, phi, phi_dot = 2.5, -3.0, 0.4, 1.5
    want = SwingUp(su.design).arm_acceleration(theta, theta_dot, phi, phi_dot)
    tau = su.command(theta, theta_dot, phi, phi_dot)
    assert plant.accelerations(theta, theta_dot, phi_dot, tau)[1] == pytest.approx(want, rel=1e-9)


def test_voltage_rig_command_is_volts_through_the_motor_model() -> None:
    rig = swing_rig("qube_servo2")
    su = SwingUp(SwingUpDesign.from_rig(rig))
    a = rig.actuator
    theta, theta_dot, phi, phi_dot = 2.0, 4.0, -0.2, 3.0
    volts = su.command(theta, theta_dot, phi, phi_dot)
    torque = a.Kt * (volts - a.Ke * phi_dot) / a.R
    want = SwingUp(su.design).arm_acceleration(theta, theta_dot, phi, phi_dot)
    assert su.design.plant.accelerations(theta, theta_dot, phi_dot, torque)[1] == pytest.approx(want, rel=1e-9)


def test_catch_and_fall_have_hysteresis() -> None:
    """Caught inside |θ| < catch_theta with the upright energy; handed back only beyond fall_theta."""
    rig = swing_rig("thesis")
    ctrl = Controller.from_rig(rig)
    d = ctrl.swing_up.design  # type: ignore[union-attr]
    assert d.catch_theta == pytest.approx(0.3) and d.fall_theta == pytest.approx(0.5)
    ctrl.reset(0.0)
    assert ctrl.update(Measurement(0.0, 0.4, 0.0, 0.0)).swinging  # outside the catch angle
    assert not ctrl.update(Measurement(0.002, 0.2, 0.0, 0.0)).swinging  # caught
    assert not ctrl.update(Measurement(0.004, 0.45, 0.0, 0.0)).swinging  # between: still balancing
    assert ctrl.update(Measurement(0.006, 0.55, 0.0, 0.0)).swinging  # fell
    trip_rig = swing_rig("thesis", on_fall="trip")
    ctrl = Controller.from_rig(trip_rig)
    ctrl.reset(0.0)
    assert not ctrl.update(Measurement(0.0, 0.1, 0.0, 0.0)).swinging
    assert not ctrl.update(Measurement(0.002, 1.0, 0.0, 0.0)).swinging  # the supervisor trips instead


def test_catch_energy_gate_refuses_a_fast_pass_through_upright() -> None:
    rig = swing_rig("thesis")
    ctrl = Controller.from_rig(rig)
    ctrl.reset(0.0)
    eps, alpha = rig.lumped().epsilon, rig.lumped().alpha
    fast = math.sqrt(2 * 0.3 * 2 * eps / alpha)  # 0.3 × 2ε of kinetic energy at upright
    assert ctrl.update(Measurement(0.0, 0.0, fast, 0.0)).swinging


def test_catch_takes_the_arm_back_from_where_it_was_caught() -> None:
    """Bumpless in φ: the balancing law starts from the arm where it was caught, at its speed (no L3·φ or L4·φ̇ step),
    and the reference returns to 0 critically damped with ω = 1/arm_return_s (1 s)."""
    rig = swing_rig("thesis")
    ctrl = Controller.from_rig(rig)
    ctrl.reset(3.0)
    ctrl.observer.reset(3.0, 1.5)  # the arm caught at 3 rad moving at 1.5 rad/s
    out = ctrl.update(Measurement(0.0, 0.0, 0.0, 3.0))
    assert not out.swinging
    assert out.u_lin == pytest.approx(0.0, abs=1e-12)  # not L3·3 rad + L4·1.5 rad/s = 2.9 N m
    h, w = 1.0 / rig.control.rate_hz, 1.0
    ref_dot = 1.5 - h * w * (w * 3.0 + 2.0 * 1.5)
    assert (ctrl.phi_ref, ctrl.phi_dot_ref) == pytest.approx((3.0 + h * ref_dot, ref_dot))
    for k in range(1, 6 * round(rig.control.rate_hz)):  # 6 s: the reference has come back
        ctrl.update(Measurement(k * h, 0.0, 0.0, ctrl.phi_ref))
    t = 6.0  # critically damped from (3, 1.5): r = (3 + 4.5 t) e^−t, ṙ = (1.5 − 4.5 t) e^−t
    assert ctrl.phi_ref == pytest.approx((3.0 + 4.5 * t) * math.exp(-t), rel=0.02)
    assert ctrl.phi_dot_ref == pytest.approx((1.5 - 4.5 * t) * math.exp(-t), rel=0.02)


def test_encoder_theta_counting_turns_is_wrapped() -> None:
    assert wrap_angle(2 * math.pi + 0.1) == pytest.approx(0.1)
    assert wrap_angle(-math.pi) == pytest.approx(-math.pi)
    rig = swing_rig("qube_servo2")
    ctrl = Controller.from_rig(rig)
    ctrl.reset(0.0)
    assert not ctrl.update(Measurement(0.0, 2 * math.pi + 0.05, 0.0, 0.0)).swinging  # upright, one turn on


def test_catch_theta_must_be_below_the_fall_angle() -> None:
    with pytest.raises(ValueError, match="catch_theta"):
        SwingUpDesign.from_rig(swing_rig("thesis", catch_theta=0.6))
