"""The physical rig as the simulator sees it: eq. 4 plant + friction + spring + actuator + sensors.

Built from a rig description (furuta_rt.config.RigConfig satisfies RigSpec) and a set of Effects
(furuta_rt.model.effects); the same builder serves the simulator, hil_mock and the diagnosis, so an effect means the
same physics everywhere. The model states what it reads of a configuration (the protocols below) rather than importing
the configuration layer above it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

from furuta_rt.model.actuator import Actuator, DCMotor
from furuta_rt.model.coupling import Coupling
from furuta_rt.model.effects import PEND, PENDULUM_COULOMB_EPSILON, Effects, JointTorque, command_timing
from furuta_rt.model.friction import Coulomb, CoulombStiction, JointFriction, LuGre, Viscous
from furuta_rt.model.parameters import LumpedParameters
from furuta_rt.model.plant import FurutaPlant
from furuta_rt.model.sensors import BesselPath, Calibration


class PlantSpec(Protocol):
    @property
    def arm_inertia(self) -> float: ...


class ActuatorSpec(Protocol):
    kind: str
    Kt: float | None
    R: float | None
    Ke: float | None


class SensorSpec(Protocol):
    bessel_cutoff: float | None
    encoder_counts_per_rev: int
    theta_rad_per_count: float
    theta_dot_rad_s_per_count: float
    theta_noise: float
    theta_dot_noise: float
    theta_wraps: bool


class RigSpec(Protocol):
    """What the rig model reads of a rig's configuration (furuta_rt.config.RigConfig)."""

    effects: Effects
    plant: PlantSpec
    actuator: ActuatorSpec
    sensors: SensorSpec

    def lumped(self) -> LumpedParameters: ...


@dataclass(frozen=True, slots=True)
class RigModel:
    plant: FurutaPlant
    arm_friction: JointFriction
    pendulum_friction: JointFriction
    actuator: Actuator
    bessel: BesselPath | None
    calibration: Calibration
    spring_k: float = 0.0
    spring_phi0: float = 0.0
    theta_offset: float = 0.0
    arm_bias: float = 0.0  # constant torque on the arm, N m
    command_latency: float | None = None  # total s from the sample instant to the torque (None: the driver's lag)
    theta_noise: float = 0.0
    theta_dot_noise: float = 0.0
    coupling: Coupling | None = None  # a compliant rotor–arm coupling (not eq. 4; simulated only when set)
    joint_torques: tuple[JointTorque, ...] = ()  # the registry's torque-law effects that are set (effects.JointTorque)

    def joint_torque(self, theta: float, theta_dot: float, phi: float, phi_dot: float) -> tuple[float, float]:
        """(τ_pendulum, τ_arm) of the torque-law effects at the states (0, 0 without any)."""
        tau_p = tau_a = 0.0
        for e in self.joint_torques:
            if e.equation == PEND:
                tau_p += e.torque(theta, theta_dot, phi, phi_dot)
            else:
                tau_a += e.torque(theta, theta_dot, phi, phi_dot)
        return tau_p, tau_a

    def command_timing(self, command_delay_ticks: int) -> tuple[int, float]:
        """(ticks the driver holds a command after its sample, s of the actuator's delay line): effects.command_timing
        for this rig's input_delay and command_latency."""
        return command_timing(command_delay_ticks, self.actuator.delay, self.command_latency)

    @classmethod
    def from_config(cls, rig: RigSpec, effects: Effects | None = None) -> RigModel:
        """The rig of ``rig`` with its own ``[effects]`` plus ``effects`` on top."""
        eff = rig.effects.merged(effects) if effects is not None else rig.effects
        p = rig.lumped()
        if eff.arm_inertia is not None:
            p = p.with_arm_inertia(rig.plant.arm_inertia, eff.arm_inertia.J)

        dry: Coulomb | CoulombStiction | None = None
        fc = eff.arm_coulomb.Fc if eff.arm_coulomb else 0.0
        if eff.arm_stiction is not None:
            dry = CoulombStiction(Fc=fc, Fs=eff.arm_stiction.Fs)
        elif eff.arm_coulomb is not None:
            dry = Coulomb(Fc=fc)
        lugre = LuGre(**eff.arm_lugre.model_dump()) if eff.arm_lugre else None
        arm = JointFriction(
            viscous=Viscous(eff.arm_viscous.Fv) if eff.arm_viscous else None, dry=dry, lugre=lugre
        )
        pend = JointFriction(
            viscous=Viscous(eff.pendulum_viscous.bp) if eff.pendulum_viscous else None,
            dry=Coulomb(eff.pendulum_coulomb.Fc, PENDULUM_COULOMB_EPSILON) if eff.pendulum_coulomb else None,
        )
        a = rig.actuator
        motor = DCMotor(Kt=a.Kt, R=a.R, Ke=a.Ke) if a.kind == "dc_motor" else None  # type: ignore[arg-type]
        actuator = Actuator(
            kind=a.kind,
            motor=motor,
            gain=eff.input_gain.gain if eff.input_gain else 1.0,
            deadzone=eff.input_deadzone.width if eff.input_deadzone else 0.0,
            limit=eff.input_saturation.limit if eff.input_saturation else None,
            delay=eff.input_delay.delay if eff.input_delay else 0.0,
        )
        s = rig.sensors
        return cls(
            plant=FurutaPlant(p),
            arm_friction=arm,
            pendulum_friction=pend,
            actuator=actuator,
            bessel=BesselPath(s.bessel_cutoff) if s.bessel_cutoff else None,
            calibration=calibration_from_config(rig),
            spring_k=eff.arm_spring.k if eff.arm_spring else 0.0,
            spring_phi0=eff.arm_spring.phi0 if eff.arm_spring else 0.0,
            theta_offset=eff.theta_offset.offset if eff.theta_offset else 0.0,
            arm_bias=eff.arm_bias.tau if eff.arm_bias else 0.0,
            command_latency=eff.command_latency.delay if eff.command_latency else None,
            theta_noise=s.theta_noise,
            theta_dot_noise=s.theta_dot_noise,
            joint_torques=eff.joint_torques(),
        )


def calibration_from_config(rig: RigSpec) -> Calibration:
    s = rig.sensors
    return Calibration(
        theta_rad_per_count=s.theta_rad_per_count,
        theta_dot_rad_s_per_count=s.theta_dot_rad_s_per_count,
        phi_counts_per_rev=s.encoder_counts_per_rev,
        theta_wraps=s.theta_wraps,
    )
