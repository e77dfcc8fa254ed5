"""Lumped parameters of the Furuta pendulum (thesis section 3.1, eq. 4).

The equations of motion depend on four numbers only:

    α = J_p + M l²          (pendulum inertia about its pivot)
    β = J + M r² + m r²     (arm inertia about the pillar, pendulum folded in)
    γ = M r l               (arm–pendulum coupling)
    ε = l g (M + m/2)       (gravity torque coefficient)

They can be built from the thesis' physical parameters (appendix C) or from the general
parametrisation most rigs publish (Cazzolato & Prime 2011: arm m1, l1, L1, J1; pendulum m2, l2, J2).
"""

from __future__ import annotations

from dataclasses import dataclass

G = 9.81


@dataclass(frozen=True, slots=True)
class LumpedParameters:
    """α, β, γ, ε of eq. 4, in SI units (kg m², kg m², kg m², N m)."""

    alpha: float
    beta: float
    gamma: float
    epsilon: float

    def __post_init__(self) -> None:
        for name in ("alpha", "beta", "epsilon"):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)!r}")
        if self.gamma < 0.0:
            raise ValueError(f"gamma must be non-negative, got {self.gamma!r}")
        if self.zeta <= 0.0:
            raise ValueError("alpha*beta - gamma^2 must be positive (the mass matrix must be positive definite)")

    @property
    def zeta(self) -> float:
        """ζ = αβ − γ², the determinant of the upright mass matrix (section 4)."""
        return self.alpha * self.beta - self.gamma**2

    def with_arm_inertia(self, J_old: float, J_new: float) -> LumpedParameters:
        """The same rig with the arm inertia J replaced (β changes by J_new − J_old)."""
        return LumpedParameters(self.alpha, self.beta - J_old + J_new, self.gamma, self.epsilon)

    @classmethod
    def from_thesis(
        cls, *, l: float, r: float, M: float, m: float, Jp: float, J: float, g: float = G
    ) -> LumpedParameters:
        """Appendix C parametrisation: pendulum length l, arm length r, tip mass M, pendulum mass m,
        pendulum inertia about its pivot Jp, arm inertia J."""
        return cls(
            alpha=Jp + M * l**2,
            beta=J + M * r**2 + m * r**2,
            gamma=M * r * l,
            epsilon=l * g * (M + m / 2.0),
        )

    @classmethod
    def from_general(
        cls,
        *,
        m1: float,
        l1: float,
        L1: float,
        J1: float,
        m2: float,
        l2: float,
        J2: float,
        g: float = G,
    ) -> LumpedParameters:
        """Cazzolato & Prime (2011), slender pendulum: arm (mass m1, centre of mass at l1, length L1,
        inertia J1 about its centre of mass) carrying a pendulum (mass m2, centre of mass at l2 from
        the pivot, inertia J2 about its centre of mass).

        α = J2 + m2 l2²,  β = J1 + m1 l1² + m2 L1²,  γ = m2 L1 l2,  ε = m2 g l2.
        """
        return cls(
            alpha=J2 + m2 * l2**2,
            beta=J1 + m1 * l1**2 + m2 * L1**2,
            gamma=m2 * L1 * l2,
            epsilon=m2 * g * l2,
        )
