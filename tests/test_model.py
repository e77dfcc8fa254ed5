"""Plant (eq. 4), linearisation (eq. 6), parametrisations and energy."""

from __future__ import annotations

import math

import numpy as np
import pytest

from furuta_rt.config import load_rig
from furuta_rt.model.parameters import LumpedParameters
from furuta_rt.model.plant import FurutaPlant
from furuta_rt.model.rig import RigModel
from furuta_rt.sim.simulator import Simulator

THESIS = dict(l=0.413, r=0.235, M=0.01, m=0.02, Jp=0.0009, J=0.05, g=9.81)


def test_lumped_parameters_of_thesis_rig() -> None:
    p = LumpedParameters.from_thesis(**THESIS)
    assert p.alpha == pytest.approx(0.0009 + 0.01 * 0.413**2)
    assert p.beta == pytest.approx(0.05 + 0.03 * 0.235**2)
    assert p.gamma == pytest.approx(0.01 * 0.235 * 0.413)
    assert p.epsilon == pytest.approx(0.413 * 9.81 * 0.02)


def test_linearisation_matches_eq6() -> None:
    p = LumpedParameters.from_thesis(**THESIS)
    A, B = FurutaPlant(p).linearize()
    z = p.zeta
    expected_A = np.array(
        [[0, 1, 0, 0], [p.beta * p.epsilon / z, 0, 0, 0], [0, 0, 0, 1], [-p.gamma * p.epsilon / z, 0, 0, 0]]
    )
    expected_B = np.array([0, -p.gamma / z, 0, p.alpha / z])
    np.testing.assert_allclose(A, expected_A, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(B.ravel(), expected_B, rtol=1e-7)
    # the numbers themselves, for the default rig
    assert A[1, 0] == pytest.approx(31.3167, rel=1e-4)
    assert B[3, 0] == pytest.approx(19.4950, rel=1e-4)


def test_general_parametrisation_reduces_to_thesis_for_point_mass_rig() -> None:
    # thesis pendulum = point mass M at l plus a uniform rod m: centre of mass and inertia about it
    l, r, M, m = 0.413, 0.235, 0.01, 0.02
    m2 = M + m
    l2 = (M * l + m * l / 2) / m2
    Jp_pivot = M * l**2 + m * l**2 / 3
    J2 = Jp_pivot - m2 * l2**2
    gen = LumpedParameters.from_general(m1=0.0, l1=0.0, L1=r, J1=0.05, m2=m2, l2=l2, J2=J2)
    # α and ε agree exactly; β, γ differ only by the rod's mass at r (the thesis folds it in β, not γ)
    assert gen.alpha == pytest.approx(Jp_pivot)
    assert gen.epsilon == pytest.approx(l * 9.81 * (M + m / 2))
    assert gen.beta == pytest.approx(0.05 + m2 * r**2)


def test_inverse_dynamics_inverts_forward_dynamics() -> None:
    plant = FurutaPlant(LumpedParameters.from_thesis(**THESIS))
    rng = np.random.default_rng(1)
    for _ in range(20):
        th, thd, phd, tau, taup = rng.normal(size=5)
        thdd, phdd = plant.accelerations(th, thd, phd, tau, taup)
        tp, ta = plant.inverse_dynamics(th, thd, phd, thdd, phdd)
        assert tp == pytest.approx(taup, abs=1e-12)
        assert ta == pytest.approx(tau, abs=1e-12)


def test_mass_matrix_must_be_positive() -> None:
    with pytest.raises(ValueError, match="positive"):
        LumpedParameters(alpha=1.0, beta=1.0, gamma=2.0, epsilon=1.0)


@pytest.mark.parametrize("theta0", [0.3, 2.5])
def test_frictionless_simulation_conserves_energy(theta0: float) -> None:
    rig = load_rig("thesis")
    model = RigModel.from_config(rig)
    sim = Simulator(model, rate_hz=500, substep_hz=10_000, x0=(theta0, 0.5, 0.0, 1.0))
    e0 = sim.energy()
    worst = 0.0
    for _ in range(10):  # 10 s
        sim.advance(500)
        worst = max(worst, abs(sim.energy() - e0) / abs(e0))
    assert worst < 1e-6
    assert sim.t == pytest.approx(10.0)
    # it really moved: the pendulum swung through a large angle
    assert abs(sim.theta - theta0) > 0.1


def test_upright_is_unstable_and_hanging_is_stable() -> None:
    plant = FurutaPlant(LumpedParameters.from_thesis(**THESIS))
    A, _ = plant.linearize()
    assert max(np.linalg.eigvals(A).real) == pytest.approx(math.sqrt(A[1, 0]), rel=1e-6)
