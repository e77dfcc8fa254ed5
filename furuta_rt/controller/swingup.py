"""Energy swing-up from hanging and the catch into balancing (Åström & Furuta, "Swinging up a pendulum by
energy control", Automatica 36, 2000), as one part of ``Controller.update``.

The pendulum's own energy, from the Lagrangian of eq. 4 with the arm still (FurutaPlant.energy at φ̇ = 0),
measured from upright:

    E = ½ α θ̇² + ε (cos θ − 1)            (0 upright at rest, −2ε hanging at rest)

With the arm accelerating at φ̈, eq. 4 gives dE/dt = −γ cos θ · θ̇ φ̈ (plus the small centrifugal term), so the
arm acceleration

    φ̈_ref = sat_a( k_E (E − E_up) · sgn(θ̇ cos θ) ) − ω_a² φ − 2 ζ_a ω_a φ̇

drives E towards E_up = margin · 2ε (monotonically while unsaturated), while a weak spring and damper keep the arm
near its zero (inside the cable's φ limit). The torque that gives φ̈_ref comes from eq. 4 itself:
τ = (φ̈_ref − φ̈|τ=0) / (∂φ̈/∂τ) (FurutaPlant.accelerations and arm_compliance); a DC motor gets the volts
V = τ R/Kt + Ke φ̇ (furuta_rt.model.actuator). The command is then saturated at the actuator's limit.

Catch and fall, with hysteresis: balancing takes over when |θ| < catch_theta and |E − 0| < catch_energy · 2ε;
it hands back (``on_fall = "swing_up"``) when |θ| > fall_theta > catch_theta.

Defaults derived from the model (``SwingUpDesign.from_rig``): the pump uses half the arm acceleration the
actuator's limit gives at rest, at most ``PHI_FRACTION`` of the φ limit times ω0² (ω0 = √(ε/α), the hanging
pendulum's frequency: the arm excursion of a pump at a scales as a/ω0²); k_E saturates the pump until the energy
is within a fifth of 2ε; the arm centring is ω_a = ω0/10, ζ_a = 1; the catch angle is 0.6 × the fall angle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from furuta_rt.config import RigConfig
from furuta_rt.model.plant import FurutaPlant

PHI_FRACTION = 0.1
"""The pump's acceleration is at most this × phi_limit × ω0²."""
ACCEL_FRACTION = 0.5
"""The pump's acceleration is at most this × what the actuator's limit gives the arm at rest."""
ENERGY_BAND = 0.05
"""The pump is saturated until the energy is within this × 2ε of its target."""
ARM_OMEGA_FRACTION = 0.1
"""The arm centring's natural frequency, × ω0."""
ARM_DAMPING_FRACTION = 0.5
"""The arm damping (per s), × ω0: it bounds the arm's speed at a/damping (a fast arm flings the pendulum out)."""
CATCH_FRACTION = 0.6
"""Default catch angle, × the fall angle."""
SIGN_DEADBAND = 0.05
"""rad/s: |θ̇ cos θ| below this keeps the pump's previous direction (no chatter at the turning points)."""


def wrap_angle(x: float) -> float:
    """x wrapped to [−π, π)."""
    return (x + math.pi) % (2.0 * math.pi) - math.pi


@dataclass(frozen=True, slots=True)
class SwingUpDesign:
    """Gains and limits of the swing-up and the catch (units: rad, s, J; the command in the rig's units)."""

    plant: FurutaPlant
    accel_max: float
    energy_gain: float
    energy_target: float  # J above the upright energy
    arm_omega: float
    arm_damping: float  # 1/s
    catch_theta: float
    catch_energy: float  # J
    fall_theta: float
    on_fall: Literal["swing_up", "trip"]
    arm_return_s: float
    period: float  # the loop's, s
    u_limit: float
    volts_per_newton_metre: float = 0.0  # R/Kt for a DC motor, 0 for a torque actuator
    back_emf: float = 0.0  # Ke (V s/rad) for a DC motor

    @classmethod
    def from_rig(cls, rig: RigConfig) -> SwingUpDesign:
        """The rig's [swing_up] with every key left out derived from the model (module docstring)."""
        c = rig.swing_up
        plant = FurutaPlant(rig.lumped())
        p = plant.p
        a = rig.actuator
        omega0 = math.sqrt(p.epsilon / p.alpha)
        torque_limit = a.limit if a.kind == "torque" else a.limit * a.Kt / a.R  # type: ignore[operator]
        accel_actuator = torque_limit * plant.arm_compliance(math.pi)
        accel_max = c.accel_max or min(ACCEL_FRACTION * accel_actuator, PHI_FRACTION * rig.safety.phi_limit * omega0**2)
        two_eps = 2.0 * p.epsilon
        fall = c.fall_theta or rig.safety.theta_limit
        catch = c.catch_theta or CATCH_FRACTION * fall
        if not catch < fall:
            raise ValueError(f"swing_up.catch_theta = {catch:g} rad must be below the fall angle {fall:g} rad "
                             "(the hysteresis between catch and fall)")
        dc = a.kind == "dc_motor"
        return cls(
            plant=plant,
            accel_max=accel_max,
            energy_gain=c.energy_gain or accel_max / (ENERGY_BAND * two_eps),
            energy_target=c.energy_margin * two_eps,
            arm_omega=c.arm_omega or ARM_OMEGA_FRACTION * omega0,
            arm_damping=c.arm_damping or ARM_DAMPING_FRACTION * omega0,
            catch_theta=catch,
            catch_energy=c.catch_energy * two_eps,
            fall_theta=fall,
            on_fall=c.on_fall,
            arm_return_s=c.arm_return_s,
            period=1.0 / rig.control.rate_hz,
            u_limit=a.limit,
            volts_per_newton_metre=a.R / a.Kt if dc else 0.0,  # type: ignore[operator]
            back_emf=float(a.Ke) if dc else 0.0,
        )


class SwingUp:
    """The swing-up law and the catch/fall tests; scalar code (it runs every tick while swinging)."""

    __slots__ = ("_sign", "design")

    def __init__(self, design: SwingUpDesign) -> None:
        self.design = design
        self._sign = 1.0

    def reset(self) -> None:
        """Start a new swing-up (the pump's first push is positive)."""
        self._sign = 1.0

    def energy(self, theta: float, theta_dot: float) -> float:
        """The pendulum's energy above upright at rest, J (eq. 4's Lagrangian with the arm still)."""
        plant = self.design.plant
        return float(plant.energy(theta, theta_dot, 0.0)) - plant.p.epsilon

    def catchable(self, theta: float, theta_dot: float) -> bool:
        """Inside the catch region: near upright with about the upright energy."""
        d = self.design
        return abs(theta) < d.catch_theta and abs(self.energy(theta, theta_dot)) < d.catch_energy

    def fallen(self, theta: float) -> bool:
        """Balancing has lost the pendulum (and the rig swings up again after a fall)."""
        return self.design.on_fall == "swing_up" and abs(theta) > self.design.fall_theta

    def arm_acceleration(self, theta: float, theta_dot: float, phi: float, phi_dot: float) -> float:
        """φ̈_ref of the energy pump and the arm centring (module docstring)."""
        d = self.design
        w = theta_dot * math.cos(theta)
        if w > SIGN_DEADBAND:
            self._sign = 1.0
        elif w < -SIGN_DEADBAND:
            self._sign = -1.0
        pump = d.energy_gain * (self.energy(theta, theta_dot) - d.energy_target) * self._sign
        lim = d.accel_max
        pump = lim if pump > lim else (-lim if pump < -lim else pump)
        wa = d.arm_omega
        return pump - wa * wa * phi - d.arm_damping * phi_dot

    def command(self, theta: float, theta_dot: float, phi: float, phi_dot: float) -> float:
        """The actuator command (N m, or V for a DC motor) for φ̈_ref, before saturation."""
        d = self.design
        accel = self.arm_acceleration(theta, theta_dot, phi, phi_dot)
        free = d.plant.accelerations(theta, theta_dot, phi_dot, 0.0)[1]
        torque = (accel - free) / d.plant.arm_compliance(theta)
        if d.volts_per_newton_metre:
            return torque * d.volts_per_newton_metre + d.back_emf * phi_dot
        return torque
