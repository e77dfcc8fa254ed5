"""Friction laws (eq. 1–3) at chosen points, and the simulator's stick/slip."""

from __future__ import annotations

import math

import numpy as np
import pytest

from furuta_rt.config import load_rig
from furuta_rt.model.effects import Effects
from furuta_rt.model.friction import Coulomb, CoulombStiction, LuGre, Viscous
from furuta_rt.model.rig import RigModel
from furuta_rt.sim.simulator import Simulator


def test_eq1_coulomb_smoothed() -> None:
    f = Coulomb(Fc=0.3, epsilon=0.1)
    assert f.torque(-0.5) == 0.3
    assert f.torque(-0.1) == 0.3  # v <= -eps
    assert f.torque(0.05) == pytest.approx(-0.15)  # -Fc v / eps
    assert f.torque(0.0) == 0.0
    assert f.torque(0.1) == -0.3
    assert f.compensation(0.05) == pytest.approx(0.15)


def test_ideal_coulomb_is_sign() -> None:
    f = Coulomb(Fc=0.2)
    assert f.torque(1e-9) == -0.2 and f.torque(-1e-9) == 0.2 and f.torque(0.0) == 0.0


def test_eq2_stiction() -> None:
    f = CoulombStiction(Fc=0.2, Fs=0.3, v_zero=0.02)
    assert f.torque(0.5) == -0.2  # sliding
    assert f.torque(0.0, external=0.25) == -0.25  # held
    assert f.torque(0.01, external=-0.1) == 0.1  # within v_zero counts as rest
    assert f.torque(0.0, external=0.5) == -0.3  # breakaway limit
    assert f.compensation(0.0, 0.1) == pytest.approx(0.1)
    with pytest.raises(ValueError):
        CoulombStiction(Fc=0.3, Fs=0.2)


def test_viscous() -> None:
    assert Viscous(0.5).torque(2.0) == -1.0
    assert Viscous(0.5).compensation(2.0) == 1.0


def test_lugre_steady_state_is_stribeck_curve() -> None:
    law = LuGre(sigma0=1e4, sigma1=1.0, Fc=0.2, Fs=0.3, vs=0.1, Fv=0.05)
    for v in (0.01, 0.1, 1.0, -0.3):
        z = 0.0
        for _ in range(2000):
            z, zd = law.advance(z, v, 1e-4)
        assert law.force(z, zd, v) == pytest.approx(law.steady_state_force(v), rel=1e-6)
    # Stribeck: Fs at v → 0, Fc + Fv v at large v
    assert law.steady_state_force(1e-6) == pytest.approx(0.3, rel=1e-4)
    assert law.steady_state_force(2.0) == pytest.approx(0.2 + 0.1, rel=1e-6)


def test_lugre_advance_solves_eq3_exactly() -> None:
    law = LuGre(sigma0=100.0, sigma1=0.5, Fc=0.2, Fs=0.3, vs=0.1)
    v, z0, h = 0.05, 1e-3, 0.01
    z1, _ = law.advance(z0, v, h)
    # fine explicit integration of dz/dt = v - |v| z / g(v)
    z = z0
    for _ in range(100000):
        z += (h / 100000) * law.z_dot(z, v)
    assert z1 == pytest.approx(z, rel=1e-6)


def test_lugre_is_stable_for_stiff_bristles() -> None:
    law = LuGre(sigma0=1e8, sigma1=0.0, Fc=0.2, Fs=0.3, vs=0.1)
    z = 0.0
    for _ in range(100):
        z, _ = law.advance(z, 1.0, 1e-3)  # rate·h ≈ 5e5: explicit Euler would explode
    assert z == pytest.approx(law.g(1.0))


def _arm_only_sim(effects: dict, torque: float, substep_hz: float = 10_000.0) -> Simulator:
    rig = load_rig("thesis")
    model = RigModel.from_config(rig, Effects.model_validate(effects))
    # pendulum hanging down (θ = π) at rest: a stable configuration to push the arm in
    sim = Simulator(model, rate_hz=500, substep_hz=substep_hz, x0=(math.pi, 0.0, 0.0, 0.0))
    sim.set_command(torque)
    return sim


def test_arm_sticks_below_breakaway_and_slides_above() -> None:
    sim = _arm_only_sim({"arm_coulomb": {"Fc": 0.2}, "arm_stiction": {"Fs": 0.3}}, torque=0.25)
    sim.advance(500)
    assert sim.stuck and sim.phi == 0.0 and sim.phi_dot == 0.0
    assert sim.arm_friction_torque == pytest.approx(-0.25, abs=1e-9)
    sim.set_command(0.35)
    sim.advance(50)
    assert not sim.stuck and sim.phi_dot > 0
    # sliding: the arm accelerates with (0.35 − Fc)/inertia about the pillar (pendulum hanging)
    p = sim.model.plant.p
    v0 = sim.phi_dot
    sim.advance(50)
    acc = (sim.phi_dot - v0) / 0.1
    assert acc == pytest.approx((0.35 - 0.2) / p.beta, rel=0.02)


def test_no_chattering_when_torque_reverses() -> None:
    sim = _arm_only_sim({"arm_coulomb": {"Fc": 0.2}}, torque=0.5)
    sim.advance(100)
    sim.set_command(0.1)  # below Fc: the arm decelerates and must come to a clean stop
    velocities = []
    for _ in range(500):
        sim.advance(1)
        velocities.append(sim.phi_dot)
    v = np.array(velocities)
    stop = int(np.argmax(v == 0.0))
    assert stop > 0 and np.all(v[stop:] == 0.0)  # stays exactly at rest
    assert np.all(v[:stop] > 0.0)  # never reversed on the way


def test_lugre_without_dry_friction_is_viscous() -> None:
    """Fc = Fs = 0 (the config's [compensation.lugre] default): g(v) = 0, the bristles hold nothing — the limit of
    eq. 3 is z = 0 and F = Fv·v, not a division by zero."""
    law = LuGre(sigma0=50.0, sigma1=1.0, Fc=0.0, Fs=0.0, vs=0.1, Fv=0.002)
    z, zd = law.advance(1e-4, 0.5, 1e-3)
    assert z == 0.0 and zd == pytest.approx(-0.1)
    z, zd = law.advance(z, -0.7, 1e-3)
    assert law.force(z, zd, -0.7) == pytest.approx(law.steady_state_force(-0.7)) == pytest.approx(-0.7 * 0.002)
