"""The compliant rotor–arm coupling (furuta_rt.model.coupling) in the simulator: off by default, the rigid arm in the
stiff limit, the arm–rotor mode at its frequency when soft."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from furuta_rt.config import load_rig
from furuta_rt.model.coupling import Coupling
from furuta_rt.model.rig import RigModel
from furuta_rt.sim.closed_loop import run_closed_loop
from furuta_rt.sim.simulator import Simulator


@pytest.fixture(scope="module")
def rig():
    return load_rig("thesis")


def test_stiff_coupling_is_the_rigid_arm(rig):
    rigid = run_closed_loop(rig, 2.0, seed=3)
    stiff = run_closed_loop(rig, 2.0, seed=3, coupling=Coupling(rotor_inertia=1e-5, stiffness=50.0, damping=0.02))
    # a 356 Hz mode with 0.02 % of the arm's inertia on the rotor: the same balancing run to a few encoder counts
    lsb = 2 * np.pi / rig.sensors.encoder_counts_per_rev
    assert np.max(np.abs(stiff.phi - rigid.phi)) < 5 * lsb
    assert np.max(np.abs(stiff.theta - rigid.theta)) < 1e-3


def test_soft_coupling_oscillates_at_its_mode(rig):
    """Open loop, pendulum hanging, the rotor released 0.01 rad from the arm: the twist φ_m − φ oscillates at
    √(k (1/J_m + 1/J_arm)) (J_arm = β, the arm's inertia with the hanging pendulum folded in), decaying with c."""
    c = Coupling(rotor_inertia=0.001, stiffness=2.5, damping=0.002)
    model = dataclasses.replace(RigModel.from_config(rig), coupling=c)
    sim = Simulator(model, 500.0, 10_000.0, x0=(np.pi, 0.0, 0.0, 0.0))
    sim.rotor = 0.01
    twist = []
    for _ in range(1000):
        sim.advance()
        twist.append(sim.rotor - sim.phi)
    twist = np.array(twist)
    crossings = np.flatnonzero(np.diff(np.sign(twist)) != 0)
    period = 2 * float(np.mean(np.diff(crossings))) / 500.0
    assert 1 / period == pytest.approx(c.mode_frequency(rig.lumped().beta), rel=0.02)
    assert np.max(np.abs(twist[-100:])) < 0.5 * np.max(np.abs(twist[:100]))  # the damper takes energy out


def test_coupling_rejects_bad_values():
    with pytest.raises(ValueError):
        Coupling(rotor_inertia=0.0, stiffness=1.0)
