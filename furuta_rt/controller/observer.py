"""Estimator of the arm velocity φ̇ from the encoder angle φ (thesis section 3.3: "a linear observer").

The arm subsystem of eq. 6 with θ (from the Bessel path) and the torque as known inputs:

    d/dt [φ, φ̇] = [φ̇,  a_θ·θ + a_φ̇·φ̇ + b_u·u],   a_θ = −γε/ζ,  b_u = α/ζ,   measurement φ

(a_φ̇ ≠ 0 and b_u scaled by Kt/R for a voltage-driven DC motor).

Discretised at the loop period h (zero-order hold), the steady-state Kalman gain comes from the
discrete algebraic Riccati equation with white arm-acceleration noise (``accel_noise``) and encoder
quantisation noise (``phi_noise``). filterpy's KalmanFilter converges to the same gain (see tests).

The torque driving the observer must be the *net* torque the arm feels: the controller passes the
linear part u_lin (the compensation is meant to cancel friction, so it is not extra torque).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, slots=True)
class ArmObserverDesign:
    """Matrices of the discrete arm observer: x⁺ = Ad x + Bd [θ, τ], y = C x, correction gain K."""

    Ad: np.ndarray
    Bd: np.ndarray
    C: np.ndarray
    K: np.ndarray
    Q: np.ndarray
    R: float
    P_prior: np.ndarray

    @classmethod
    def design(
        cls, A: np.ndarray, B: np.ndarray, h: float, accel_noise: float, phi_noise: float
    ) -> ArmObserverDesign:
        """From the (actuated) linearisation (A, B) of eq. 6; ZOH discretisation at period h."""
        import scipy.linalg  # here, not above: the real-time process gets the matrices made (controller.design_in_helper)

        Ac = np.array([[0.0, 1.0], [0.0, A[3, 3]]])
        Bc = np.array([[0.0, 0.0], [A[3, 0], B[3, 0]]])
        M = scipy.linalg.expm(np.block([[Ac, Bc], [np.zeros((2, 4))]]) * h)
        Ad, Bd = M[:2, :2], M[:2, 2:]
        C = np.array([[1.0, 0.0]])
        G = np.array([[0.5 * h * h], [h]])
        Q = G @ G.T * accel_noise**2
        R = float(phi_noise**2)
        P = scipy.linalg.solve_discrete_are(Ad.T, C.T, Q, np.array([[R]]))
        K = P @ C.T / (C @ P @ C.T + R)
        return cls(Ad=Ad, Bd=Bd, C=C, K=K.ravel(), Q=Q, R=R, P_prior=P)


class ArmObserver:
    """Steady-state Kalman filter for [φ, φ̇] in scalar code (runs every tick)."""

    __slots__ = ("_a00", "_a01", "_a11", "_b00", "_b01", "_b10", "_b11", "_k0", "_k1", "design", "phi", "phi_dot")

    def __init__(self, design: ArmObserverDesign) -> None:
        self.design = design
        self._a00, self._a01 = float(design.Ad[0, 0]), float(design.Ad[0, 1])
        self._a11 = float(design.Ad[1, 1])
        self._b00, self._b01 = float(design.Bd[0, 0]), float(design.Bd[0, 1])
        self._b10, self._b11 = float(design.Bd[1, 0]), float(design.Bd[1, 1])
        self._k0, self._k1 = float(design.K[0]), float(design.K[1])
        self.phi = 0.0
        self.phi_dot = 0.0

    def reset(self, phi: float, phi_dot: float = 0.0) -> None:
        self.phi = phi
        self.phi_dot = phi_dot

    def correct(self, phi_measured: float) -> float:
        """Measurement update with φ; returns the posterior φ̇ estimate."""
        innovation = phi_measured - self.phi
        self.phi += self._k0 * innovation
        self.phi_dot += self._k1 * innovation
        return self.phi_dot

    def predict(self, theta: float, torque: float) -> None:
        """Time update over one period with θ and the net arm torque held over it."""
        phi, phi_dot = self.phi, self.phi_dot
        self.phi = self._a00 * phi + self._a01 * phi_dot + self._b00 * theta + self._b01 * torque
        self.phi_dot = self._a11 * phi_dot + self._b10 * theta + self._b11 * torque
