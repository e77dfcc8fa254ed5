"""Physics beyond the nominal eq. 4 model, named with the vocabulary shared by hil_mock and diagnose.

Each effect has SI parameters. A rig configuration lists the effects it knows about; hil_mock adds
more (``--effect arm_coulomb.Fc=0.3``); ``diagnose`` reports what it finds in the same names:

    arm_coulomb {Fc}            arm_viscous {Fv}           arm_stiction {Fs} (breakaway; sliding = arm_coulomb)
    arm_lugre {sigma0, sigma1, Fc, Fs, vs, Fv}              pendulum_viscous {bp}   pendulum_coulomb {Fc}
    theta_offset {offset}       input_delay {delay}        input_deadzone {width}  input_gain {gain}
    input_saturation {limit}    arm_spring {k, phi0}       arm_inertia {J}
    arm_bias {tau}              command_latency {delay}

Latency: the rig's configuration says the command answering the sample of tick k acts from
t_k + command_delay_ticks·h; ``input_delay`` is an extra transport delay of the actuator ON TOP of that
(≥ 0). ``command_latency`` is the TOTAL time from the sample instant to the torque acting (s, may be
shorter than command_delay_ticks·h): when it is set it replaces command_delay_ticks·h + input_delay
(an input_delay given as well is ignored by the simulator; diagnose reports one or the other).
"""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, Field, model_validator


class _Effect(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class ArmCoulomb(_Effect):
    Fc: float = Field(ge=0, description="sliding friction torque on the arm, N m")


class ArmViscous(_Effect):
    Fv: float = Field(ge=0, description="viscous friction on the arm, N m s/rad")


class ArmStiction(_Effect):
    Fs: float = Field(ge=0, description="breakaway torque of the arm, N m")


class ArmLuGre(_Effect):
    sigma0: float = Field(gt=0)
    sigma1: float = Field(ge=0)
    Fc: float = Field(ge=0)
    Fs: float = Field(ge=0)
    vs: float = Field(gt=0)
    Fv: float = Field(default=0.0, ge=0)

    @model_validator(mode="after")
    def _fs_above_fc(self) -> ArmLuGre:
        if self.Fs < self.Fc:
            raise ValueError("Fs must be >= Fc")
        return self


class PendulumViscous(_Effect):
    bp: float = Field(ge=0, description="viscous friction at the pendulum pivot, N m s/rad")


class PendulumCoulomb(_Effect):
    Fc: float = Field(ge=0, description="Coulomb friction at the pendulum pivot, N m")


class ThetaOffset(_Effect):
    offset: float = Field(description="rad the θ sensor adds to the true θ")


class InputDelay(_Effect):
    delay: float = Field(ge=0, le=0.5, description="transport delay of the actuator command, s")


class CommandLatency(_Effect):
    delay: float = Field(ge=0, le=0.5, description="total s from the sample instant to the torque acting "
                         "(replaces command_delay_ticks·h + input_delay)")


class ArmBias(_Effect):
    tau: float = Field(description="constant torque on the arm, N m (cable drag, driver offset, tilted base)")


class InputDeadzone(_Effect):
    width: float = Field(ge=0, description="half-width of the dead band, N m")


class InputGain(_Effect):
    gain: float = Field(gt=0, description="actual torque per commanded torque")


class InputSaturation(_Effect):
    limit: float = Field(gt=0, description="largest torque the actuator delivers, N m")


class ArmSpring(_Effect):
    k: float = Field(ge=0, description="cable stiffness on the arm, N m/rad")
    phi0: float = Field(default=0.0, description="arm angle where the cable is relaxed, rad")


class ArmInertia(_Effect):
    J: float = Field(gt=0, description="the arm's actual inertia J (thesis parametrisation), kg m²")


EFFECT_TYPES: dict[str, type[_Effect]] = {
    "arm_coulomb": ArmCoulomb,
    "arm_viscous": ArmViscous,
    "arm_stiction": ArmStiction,
    "arm_lugre": ArmLuGre,
    "pendulum_viscous": PendulumViscous,
    "pendulum_coulomb": PendulumCoulomb,
    "theta_offset": ThetaOffset,
    "input_delay": InputDelay,
    "input_deadzone": InputDeadzone,
    "input_gain": InputGain,
    "input_saturation": InputSaturation,
    "arm_spring": ArmSpring,
    "arm_inertia": ArmInertia,
    "arm_bias": ArmBias,
    "command_latency": CommandLatency,
}


class Effects(_Effect):
    """A set of named effects; absent ones are not present in the physics."""

    arm_coulomb: ArmCoulomb | None = None
    arm_viscous: ArmViscous | None = None
    arm_stiction: ArmStiction | None = None
    arm_lugre: ArmLuGre | None = None
    pendulum_viscous: PendulumViscous | None = None
    pendulum_coulomb: PendulumCoulomb | None = None
    theta_offset: ThetaOffset | None = None
    input_delay: InputDelay | None = None
    input_deadzone: InputDeadzone | None = None
    input_gain: InputGain | None = None
    input_saturation: InputSaturation | None = None
    arm_spring: ArmSpring | None = None
    arm_inertia: ArmInertia | None = None
    arm_bias: ArmBias | None = None
    command_latency: CommandLatency | None = None

    @model_validator(mode="after")
    def _consistent(self) -> Effects:
        if self.arm_lugre is not None and (self.arm_coulomb or self.arm_stiction):
            raise ValueError("arm_lugre already contains Coulomb and stiction; do not combine it with them")
        if self.arm_stiction is not None:
            fc = self.arm_coulomb.Fc if self.arm_coulomb else 0.0
            if self.arm_stiction.Fs < fc:
                raise ValueError("arm_stiction.Fs (breakaway) must be >= arm_coulomb.Fc (sliding)")
        return self

    def present(self) -> dict[str, dict[str, float]]:
        """{name: params} of the effects that are set, in the diagnose JSON shape."""
        return {
            name: getattr(self, name).model_dump()
            for name in EFFECT_TYPES
            if getattr(self, name) is not None
        }

    def merged(self, other: Effects | dict[str, Any]) -> Effects:
        """These effects with ``other``'s set on top (other wins per effect)."""
        data = self.present()
        extra = other.present() if isinstance(other, Effects) else other
        data.update(extra)
        return Effects.model_validate(data)


def parse_effect_assignment(text: str) -> tuple[str, str, float]:
    """Parse ``name.param=value`` (the hil-mock ``--effect`` syntax)."""
    try:
        lhs, value = text.split("=", 1)
        name, param = lhs.strip().split(".", 1)
    except ValueError:
        raise ValueError(f"effect {text!r} is not of the form name.param=value (e.g. arm_coulomb.Fc=0.3)") from None
    try:
        number = float(value)
    except ValueError:
        raise ValueError(f"effect {text!r}: the value {value.strip()!r} is not a number (e.g. {lhs.strip()}=0.3)") from None
    if name not in EFFECT_TYPES:
        raise ValueError(f"unknown effect {name!r}; known effects: {', '.join(EFFECT_TYPES)}")
    if param not in EFFECT_TYPES[name].model_fields:
        known = ", ".join(EFFECT_TYPES[name].model_fields)
        raise ValueError(f"effect {name!r} has no parameter {param!r}; its parameters: {known}")
    return name, param, number


def effects_from_assignments(assignments: list[str], base: Effects | None = None) -> Effects:
    """Build Effects from ``name.param=value`` strings on top of ``base``."""
    data: dict[str, dict[str, float]] = {}
    for text in assignments:
        name, param, value = parse_effect_assignment(text)
        data.setdefault(name, {})[param] = value
    base = base or Effects()
    merged = base.present()
    for name, params in data.items():
        merged[name] = {**merged.get(name, {}), **params}
    return Effects.model_validate(merged)
