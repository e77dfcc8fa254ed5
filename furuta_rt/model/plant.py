"""The nonlinear Furuta pendulum, eq. 4, and its linearisation about upright, eq. 6.

State x = [θ, θ̇, φ, φ̇]; θ = 0 upright; τ_arm is the torque on the arm (u in the thesis) and τ_pend
a torque on the pendulum pivot (friction there). Eq. 4 in matrix form:

    [ α              γ cos θ        ] [θ̈]   [ α φ̇² sin θ cos θ + ε sin θ + τ_pend                 ]
    [ γ cos θ        β + α sin² θ   ] [φ̈] = [ γ θ̇² sin θ − 2α θ̇ φ̇ sin θ cos θ + τ_arm            ]

It follows from the Lagrangian with T = ½[(β + α sin²θ) φ̇² + 2γ cos θ θ̇ φ̇ + α θ̇²] and V = ε cos θ,
so E = T + V is conserved without friction or input.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from furuta_rt.model.parameters import LumpedParameters


@dataclass(frozen=True, slots=True)
class FurutaPlant:
    """Rigid-body dynamics of eq. 4 for given lumped parameters."""

    p: LumpedParameters

    def accelerations(
        self, theta: float, theta_dot: float, phi_dot: float, tau_arm: float, tau_pend: float = 0.0
    ) -> tuple[float, float]:
        """(θ̈, φ̈) from eq. 4 by solving the 2×2 mass matrix (scalar code: this is the hot path)."""
        a, b, c, e = self.p.alpha, self.p.beta, self.p.gamma, self.p.epsilon
        s = math.sin(theta)
        co = math.cos(theta)
        m11 = a
        m12 = c * co
        m22 = b + a * s * s
        f1 = a * phi_dot * phi_dot * s * co + e * s + tau_pend
        f2 = c * theta_dot * theta_dot * s - 2.0 * a * theta_dot * phi_dot * s * co + tau_arm
        det = m11 * m22 - m12 * m12
        return (m22 * f1 - m12 * f2) / det, (m11 * f2 - m12 * f1) / det

    def arm_compliance(self, theta: float) -> float:
        """∂φ̈/∂τ_arm = (M⁻¹)₂₂ = α / det M(θ): how much one N m on the arm accelerates it."""
        a = self.p.alpha
        s = math.sin(theta)
        co = math.cos(theta)
        m22 = self.p.beta + a * s * s
        return a / (a * m22 - (self.p.gamma * co) ** 2)

    def inverse_dynamics(
        self, theta: float, theta_dot: float, phi_dot: float, theta_ddot: float, phi_ddot: float
    ) -> tuple[float, float]:
        """(τ_pend, τ_arm) that eq. 4 needs to produce the given accelerations. Works on arrays too."""
        a, b, c, e = self.p.alpha, self.p.beta, self.p.gamma, self.p.epsilon
        s = np.sin(theta)
        co = np.cos(theta)
        tau_pend = a * theta_ddot + c * co * phi_ddot - a * phi_dot**2 * s * co - e * s
        tau_arm = (
            c * co * theta_ddot
            + (b + a * s**2) * phi_ddot
            - c * theta_dot**2 * s
            + 2.0 * a * theta_dot * phi_dot * s * co
        )
        return tau_pend, tau_arm

    def energy(self, theta: float, theta_dot: float, phi_dot: float) -> float:
        """Total mechanical energy T + V (J); V = ε cos θ, so upright at rest has E = ε. Works on arrays too."""
        a, b, c, e = self.p.alpha, self.p.beta, self.p.gamma, self.p.epsilon
        s = np.sin(theta)
        co = np.cos(theta)
        kinetic = 0.5 * ((b + a * s * s) * phi_dot**2 + 2.0 * c * co * theta_dot * phi_dot + a * theta_dot**2)
        return kinetic + e * co

    def linearize(self, eps: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
        """(A, B) of eq. 6 about x = 0, by central differences of `accelerations` (not typed in)."""
        A = np.zeros((4, 4))
        B = np.zeros((4, 1))
        A[0, 1] = 1.0
        A[2, 3] = 1.0
        for j, idx in enumerate((0, 1, 3)):
            xp = [0.0, 0.0, 0.0]
            xm = [0.0, 0.0, 0.0]
            xp[j] = eps
            xm[j] = -eps
            ap = self.accelerations(xp[0], xp[1], xp[2], 0.0)
            am = self.accelerations(xm[0], xm[1], xm[2], 0.0)
            A[1, idx] = (ap[0] - am[0]) / (2 * eps)
            A[3, idx] = (ap[1] - am[1]) / (2 * eps)
        up = self.accelerations(0.0, 0.0, 0.0, eps)
        um = self.accelerations(0.0, 0.0, 0.0, -eps)
        B[1, 0] = (up[0] - um[0]) / (2 * eps)
        B[3, 0] = (up[1] - um[1]) / (2 * eps)
        return A, B
