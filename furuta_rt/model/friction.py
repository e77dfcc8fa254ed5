"""Friction laws of thesis section 2.2, as torques on a joint.

Convention: every law returns the friction *torque acting on the joint*, which opposes motion
(negative for v > 0). The same objects serve two roles:

* the plant's friction in the simulator, hil_mock and the diagnosis, and
* the compensator term F̂ of u = L·x + F̂, via ``compensation`` (the torque that cancels the law).

Laws: viscous, Coulomb with the ε-smoothed transition (eq. 1), Coulomb + stiction (eq. 2) and
LuGre (eq. 3).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


def law_on_array(law_torque, v: np.ndarray) -> np.ndarray:
    """A scalar friction law of this module (its ``torque``) evaluated on an array of velocities."""
    return np.vectorize(law_torque, otypes=[float])(v)


def _sign(v: float) -> float:
    return 1.0 if v > 0.0 else (-1.0 if v < 0.0 else 0.0)


@dataclass(frozen=True, slots=True)
class Viscous:
    """F = −Fv·v (the fully lubricated regime; Fv in N m s/rad)."""

    Fv: float

    def __post_init__(self) -> None:
        if self.Fv < 0:
            raise ValueError(f"viscous coefficient Fv must be >= 0, got {self.Fv}")

    def torque(self, v: float, external: float = 0.0) -> float:
        return -self.Fv * v

    def compensation(self, v_hat: float, u_external: float = 0.0) -> float:
        return self.Fv * v_hat


@dataclass(frozen=True, slots=True)
class Coulomb:
    """Eq. 1: F = Fc for v ≤ −ε, −Fc·v/ε for |v| < ε, −Fc for v ≥ ε.

    With ε = 0 this is ideal Coulomb friction F = −Fc·sgn(v); the simulator then treats the contact as
    set-valued (it sticks at v = 0 while the other torques stay within ±Fc).
    """

    Fc: float
    epsilon: float = 0.0

    def __post_init__(self) -> None:
        if self.Fc < 0 or self.epsilon < 0:
            raise ValueError(f"Coulomb Fc and epsilon must be >= 0, got Fc={self.Fc}, epsilon={self.epsilon}")

    @property
    def sliding_level(self) -> float:
        return self.Fc

    @property
    def stick_limit(self) -> float:
        """Largest torque the contact holds at rest."""
        return self.Fc

    def torque(self, v: float, external: float = 0.0) -> float:
        if self.epsilon > 0.0 and -self.epsilon < v < self.epsilon:
            return -self.Fc * v / self.epsilon
        return -self.Fc * _sign(v)

    def compensation(self, v_hat: float, u_external: float = 0.0) -> float:
        return -self.torque(v_hat)


@dataclass(frozen=True, slots=True)
class CoulombStiction:
    """Eq. 2: sliding F = −Fc·sgn(v); at rest (|v| ≤ v_zero) F = −F_e while |F_e| ≤ Fs, else −Fs·sgn(F_e).

    F_e is the external torque on the joint. The thesis treats |φ̇| ≤ 0.02 rad/s as rest in its
    simulation (section 6.1); ``v_zero`` is that threshold for the compensator. The simulator uses the
    exact set-valued law (v = 0 exactly while stuck).
    """

    Fc: float
    Fs: float
    v_zero: float = 0.02

    def __post_init__(self) -> None:
        if self.Fc < 0 or self.Fs < self.Fc:
            raise ValueError(f"stiction needs 0 <= Fc <= Fs, got Fc={self.Fc}, Fs={self.Fs}")
        if self.v_zero < 0:
            raise ValueError(f"v_zero must be >= 0, got {self.v_zero}")

    @property
    def sliding_level(self) -> float:
        return self.Fc

    @property
    def stick_limit(self) -> float:
        return self.Fs

    def torque(self, v: float, external: float = 0.0) -> float:
        if abs(v) > self.v_zero:
            return -self.Fc * _sign(v)
        if abs(external) <= self.Fs:
            return -external
        return -self.Fs * _sign(external)

    def compensation(self, v_hat: float, u_external: float = 0.0) -> float:
        """Cancel the law with the controller's own torque taken as the external torque F_e."""
        return -self.torque(v_hat, u_external)


@dataclass(frozen=True, slots=True)
class LuGre:
    """Eq. 3 (Canudas de Wit et al.): bristle deflection z,

        dz/dt = v − |v| z / g(v),   g(v) = (Fc + (Fs − Fc) e^{−(v/vs)²}) / σ0,
        F = σ0 z + σ1 dz/dt + Fv v     (the force resisting motion; the joint torque is −F).
    """

    sigma0: float
    sigma1: float
    Fc: float
    Fs: float
    vs: float
    Fv: float = 0.0

    def __post_init__(self) -> None:
        if self.sigma0 <= 0 or self.sigma1 < 0 or self.Fc < 0 or self.Fs < self.Fc or self.vs <= 0:
            raise ValueError(
                "LuGre needs sigma0 > 0, sigma1 >= 0, 0 <= Fc <= Fs, vs > 0; got "
                f"sigma0={self.sigma0}, sigma1={self.sigma1}, Fc={self.Fc}, Fs={self.Fs}, vs={self.vs}"
            )

    def g(self, v: float) -> float:
        """σ0·g(v) = Fc + (Fs − Fc)·e^(−(v/vs)²) (eq. 3), divided by σ0; ``v`` may be an array (the diagnosis)."""
        exp = np.exp if isinstance(v, np.ndarray) else math.exp
        return (self.Fc + (self.Fs - self.Fc) * exp(-((v / self.vs) ** 2))) / self.sigma0

    def z_dot(self, z: float, v: float) -> float:
        return v - abs(v) * z / self.g(v)

    def force(self, z: float, z_dot: float, v: float) -> float:
        """F of eq. 3 (resisting force, positive when sliding forward)."""
        return self.sigma0 * z + self.sigma1 * z_dot + self.Fv * v

    def torque(self, z: float, z_dot: float, v: float) -> float:
        return -self.force(z, z_dot, v)

    def steady_state_force(self, v: float) -> float:
        """The Stribeck curve: F at constant velocity (z at its equilibrium g(v)·sgn v); ``v`` may be an array."""
        sign = np.sign(v) if isinstance(v, np.ndarray) else _sign(v)
        return self.sigma0 * self.g(v) * sign + self.Fv * v

    def advance(self, z: float, v: float, h: float) -> tuple[float, float]:
        """Exact solution of dz/dt over a step h with v held constant: (z_next, mean dz/dt).

        The bristle equation is linear in z for fixed v, so z relaxes exponentially towards
        g(v)·sgn(v) with rate σ0|v|/(σ0 g). Stable for any stiffness σ0 and step h.
        """
        if v == 0.0:
            return z, 0.0
        # g(v) of eq. 3, written out: this runs every tick of a LuGre compensator (the same operations as ``g``)
        g = (self.Fc + (self.Fs - self.Fc) * math.exp(-((v / self.vs) ** 2))) / self.sigma0
        if g == 0.0:  # Fc = Fs = 0: no dry friction, the bristles hold nothing (the limit rate → ∞, z → 0 at once)
            return 0.0, -z / h
        rate = abs(v) / g
        z_ss = v / rate
        z_next = z_ss + (z - z_ss) * math.exp(-rate * h)
        return z_next, (z_next - z) / h


DryFriction = Coulomb | CoulombStiction


@dataclass(frozen=True, slots=True)
class JointFriction:
    """All friction at one joint: viscous + (dry set-valued law or LuGre). Unused parts are None."""

    viscous: Viscous | None = None
    dry: DryFriction | None = None
    lugre: LuGre | None = None

    def __post_init__(self) -> None:
        if self.dry is not None and self.lugre is not None:
            raise ValueError("a joint has either a static dry-friction law or LuGre, not both")

    @property
    def is_frictionless(self) -> bool:
        return self.viscous is None and self.dry is None and self.lugre is None
