"""Actuator chain: command → delay → gain → deadzone → saturation → torque on the arm.

The command is a torque in N m (``kind = "torque"``, the thesis' setting) or a motor voltage in V
(``kind = "dc_motor"``): τ = Kt·(V − Ke·φ̇)/R, so the back-EMF acts as viscous damping Kt·Ke/R.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal


@dataclass(frozen=True, slots=True)
class DCMotor:
    """Voltage-driven DC motor on the arm: torque constant Kt (N m/A), winding resistance R (Ω),
    back-EMF constant Ke (V s/rad), optional gear ratio already folded into Kt and Ke."""

    Kt: float
    R: float
    Ke: float

    def __post_init__(self) -> None:
        if self.Kt <= 0 or self.R <= 0 or self.Ke < 0:
            raise ValueError(f"DC motor needs Kt > 0, R > 0, Ke >= 0; got Kt={self.Kt}, R={self.R}, Ke={self.Ke}")

    @property
    def torque_per_volt(self) -> float:
        return self.Kt / self.R

    @property
    def back_emf_damping(self) -> float:
        """N m s/rad of viscous-like damping from the back-EMF."""
        return self.Kt * self.Ke / self.R

    def torque(self, volts: float, arm_velocity: float) -> float:
        return self.Kt * (volts - self.Ke * arm_velocity) / self.R


@dataclass(frozen=True, slots=True)
class Actuator:
    """Command shaping between the controller's number and the arm.

    ``gain``: multiplies the command (1 = nominal). ``deadzone``: half-width of the dead band
    (commands with |u| ≤ deadzone produce nothing; above it the output is u − deadzone·sgn u).
    ``limit``: saturation of the command (N m or V; None = unlimited). ``delay``: transport delay (s)
    on top of the one-tick command latency of the protocol.
    """

    kind: Literal["torque", "dc_motor"] = "torque"
    motor: DCMotor | None = None
    gain: float = 1.0
    deadzone: float = 0.0
    limit: float | None = None
    delay: float = 0.0

    def __post_init__(self) -> None:
        if self.kind == "dc_motor" and self.motor is None:
            raise ValueError("actuator kind 'dc_motor' needs motor parameters (Kt, R, Ke)")
        if self.deadzone < 0 or self.delay < 0 or (self.limit is not None and self.limit <= 0):
            raise ValueError("actuator deadzone and delay must be >= 0 and limit > 0")

    def shape(self, command: float) -> float:
        """Gain, deadzone and saturation applied to a command (delay is the simulator's business)."""
        u = command * self.gain
        dz = self.deadzone
        if dz > 0.0:
            if -dz <= u <= dz:
                u = 0.0
            else:
                u = u - dz if u > 0 else u + dz
        lim = self.limit
        if lim is not None:
            u = lim if u > lim else (-lim if u < -lim else u)
        return u

    def torque_terms(self, command: float) -> tuple[float, float]:
        """(τ0, d): the arm torque is τ0 − d·φ̇ for the shaped command (d > 0 only for a DC motor)."""
        u = self.shape(command)
        if self.kind == "torque" or self.motor is None:
            return u, 0.0
        return u * self.motor.torque_per_volt, self.motor.back_emf_damping
