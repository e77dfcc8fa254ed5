"""State-feedback design for u = L·x (thesis section 3.2).

* ``pole_placement_gains``: the thesis' closed form, eq. 7, placing the poles at
  (s² + 2ζ1ω1 s + ω1²)(s² + 2ζ2ω2 s + ω2²) for the linearisation of eq. 6.
* ``place_gains``: the same via python-control's ``place`` (the cross-check).
* ``lqr_gains``: an LQR alternative.

Sign convention as in the thesis: u = +L·x, so the closed loop is ẋ = (A + B L) x.
"""

from __future__ import annotations

import numpy as np

from furuta_rt.config import ActuatorConfig
from furuta_rt.model.parameters import LumpedParameters
from furuta_rt.model.plant import FurutaPlant


def target_polynomial(omega1: float, omega2: float, zeta1: float, zeta2: float) -> np.ndarray:
    """Coefficients of (s² + 2ζ1ω1 s + ω1²)(s² + 2ζ2ω2 s + ω2²), highest power first."""
    return np.polymul([1.0, 2 * zeta1 * omega1, omega1**2], [1.0, 2 * zeta2 * omega2, omega2**2])


def target_poles(omega1: float, omega2: float, zeta1: float, zeta2: float) -> np.ndarray:
    return np.roots(target_polynomial(omega1, omega2, zeta1, zeta2))


def pole_placement_gains(
    p: LumpedParameters, omega1: float = 3.0, omega2: float = 7.0, zeta1: float = 0.7, zeta2: float = 0.7
) -> np.ndarray:
    """Eq. 7: L = [l1, l2, l3, l4] in closed form from α, β, γ, ε."""
    a, b, g, e, z = p.alpha, p.beta, p.gamma, p.epsilon, p.zeta
    if g == 0.0:
        raise ValueError("gamma = 0: the arm does not couple to the pendulum, eq. 7 is undefined")
    w1, w2 = omega1, omega2
    c2 = w1**2 + w2**2 + 4 * zeta1 * zeta2 * w1 * w2
    c1 = 2 * zeta1 * w1 * w2**2 + 2 * zeta2 * w1**2 * w2
    c0 = w1**2 * w2**2
    l1 = e * b / g + z / g * (a / e * c0 + c2)
    l2 = z / g * (a / e * c1 + 2 * zeta1 * w1 + 2 * zeta2 * w2)
    l3 = z / e * c0
    l4 = z / e * c1
    return np.array([l1, l2, l3, l4])


def place_gains(plant: FurutaPlant, poles: np.ndarray, actuator: ActuatorConfig | None = None) -> np.ndarray:
    """L by python-control's ``place`` on eq. 6 (K of A − BK, so L = −K)."""
    import control  # imported here, not above: it pulls in scipy.signal and matplotlib, ~2 s of every CLI start

    A, B = actuated_linearization(plant, actuator) if actuator else plant.linearize()
    K = control.place(A, B, poles)
    return -np.asarray(K).ravel()


def lqr_gains(
    plant: FurutaPlant, Q: list[float] | np.ndarray, R: float, actuator: ActuatorConfig | None = None
) -> np.ndarray:
    """Continuous LQR on eq. 6 with diagonal Q and scalar R; returns L = −K."""
    import control  # see place_gains

    A, B = actuated_linearization(plant, actuator) if actuator else plant.linearize()
    K, _, _ = control.lqr(A, B, np.diag(np.asarray(Q, dtype=float)), np.array([[R]]))
    return -np.asarray(K).ravel()


def characteristic_polynomial(p: LumpedParameters, L: np.ndarray) -> np.ndarray:
    """det(sI − A − BL) for eq. 6 with u = L·x (monic, highest power first):

    s⁴ + (γl2 − αl4)/ζ s³ + (γl1 − αl3 − βε)/ζ s² + εl4/ζ s + εl3/ζ

    The thesis prints the s³ and s² coefficients with the opposite sign (a typo: eq. 7 is derived
    from, and the denominators of section 4 use, the form above).
    """
    a, b, g, e, z = p.alpha, p.beta, p.gamma, p.epsilon, p.zeta
    l1, l2, l3, l4 = L
    return np.array([1.0, (g * l2 - a * l4) / z, (g * l1 - a * l3 - b * e) / z, e * l4 / z, e * l3 / z])


def actuated_linearization(plant: FurutaPlant, actuator: ActuatorConfig) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 6 with the actuator in front: for a DC motor the input is a voltage, τ = Kt(V − Ke φ̇)/R,
    so B scales by Kt/R and the back-EMF adds −(Kt Ke/R)·B to the φ̇ column of A."""
    A, B = plant.linearize()
    if actuator.kind == "dc_motor":
        k_v = actuator.Kt / actuator.R  # type: ignore[operator]
        damping = actuator.Kt * actuator.Ke / actuator.R  # type: ignore[operator]
        A = A.copy()
        A[:, 3] -= B[:, 0] * damping
        B = B * k_v
    return A, B
