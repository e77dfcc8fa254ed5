"""A compliant arm coupling: the motor's rotor drives the arm through a torsional spring and damper.

Not part of the thesis' eq. 4, whose arm is rigid (the command torque acts on the arm itself). With a coupling the
rotor (inertia J_m, angle φ_m) is a separate body:

    J_m φ̈_m = τ_motor − τ_c,    τ_c = k (φ_m − φ) + c (φ̇_m − φ̇),

and the arm row of eq. 4 receives τ_c instead of τ_motor. The arm–rotor mode sits at
ω = √(k (1/J_m + 1/J_arm)). Used by the simulator only when configured (a mismatch outside the diagnose library).
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class Coupling:
    rotor_inertia: float  # J_m, kg m²
    stiffness: float  # k, N m/rad
    damping: float = 0.0  # c, N m s/rad

    def __post_init__(self) -> None:
        if not (self.rotor_inertia > 0 and self.stiffness > 0 and self.damping >= 0):
            raise ValueError("a coupling needs rotor_inertia > 0, stiffness > 0, damping ≥ 0")

    def torque(self, rotor: float, rotor_dot: float, phi: float, phi_dot: float) -> float:
        """τ_c on the arm (and −τ_c on the rotor)."""
        return self.stiffness * (rotor - phi) + self.damping * (rotor_dot - phi_dot)

    def advance(self, rotor: float, rotor_dot: float, tau_motor: float, phi: float, phi_dot: float,
                h: float) -> tuple[float, float, float]:
        """(φ_m, φ̇_m after h, τ_c during h): semi-implicit Euler of the rotor with the arm's state held."""
        tau_c = self.torque(rotor, rotor_dot, phi, phi_dot)
        rotor_dot += h * (tau_motor - tau_c) / self.rotor_inertia
        return rotor + h * rotor_dot, rotor_dot, tau_c

    def mode_frequency(self, arm_inertia: float) -> float:
        """The arm–rotor mode, Hz (undamped, the arm free)."""
        return math.sqrt(self.stiffness * (1 / self.rotor_inertia + 1 / arm_inertia)) / (2 * math.pi)
