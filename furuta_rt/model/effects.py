"""Physics beyond the nominal eq. 4 model, named with the vocabulary shared by hil_mock and diagnose.

Each effect is one class below (its registry entry, EFFECT_TYPES) with SI parameters as its fields. A rig
configuration lists the effects it knows about; hil_mock adds more (``--effect arm_coulomb.Fc=0.3``); ``diagnose``
reports what it finds in the same names (arm_stiction is the breakaway; its sliding level is arm_coulomb).

Latency: the rig's configuration says the command answering the sample of tick k acts from
t_k + command_delay_ticks·h; ``input_delay`` is an extra transport delay of the actuator ON TOP of that
(≥ 0). ``command_latency`` is the TOTAL time from the sample instant to the torque acting (s, may be
shorter than command_delay_ticks·h): when it is set it replaces command_delay_ticks·h + input_delay
(an input_delay given as well is ignored by the simulator; diagnose reports one or the other).
"""

from __future__ import annotations

from typing import Any, ClassVar

from pydantic import BaseModel, ConfigDict, Field, create_model, model_validator

ARM, PEND = "arm", "pendulum"  # the rows of eq. 4 an effect can act in

EFFECT_TYPES: dict[str, type[_Effect]] = {}
"""The effect registry: every effect class by its name, in definition order. A class registers itself by naming
itself (``name = "..."``); the rig configuration (Effects), the rig model and simulator (joint torques), hil_mock and
diagnose's regression library all read this one table."""


class _Effect(BaseModel):
    """One named physical effect: its SI parameters are its fields; what the rest of the project needs to know about
    it besides — which row of eq. 4 it acts in, the parameter that measures its size, the effects it may be mistaken
    for and the experiments that tell them apart — are its class attributes."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: ClassVar[str] = ""  # its key in a rig's [effects], in hil-mock's --effect and in diagnose's report
    equation: ClassVar[str] = ARM  # the row of eq. 4 it acts in (ARM or PEND)
    main: ClassVar[str] = ""  # the parameter that measures its size (default: the first)
    lookalikes: ClassVar[tuple[str, ...]] = ()  # effects the data may confuse it with, tried in its place by diagnose
    experiments: ClassVar[dict[str, str]] = {}  # another effect -> the experiment that tells the two apart
    searched: ClassVar[bool] = True  # diagnose tries it on every recording (False: only when asked, --also-search)

    @classmethod
    def __pydantic_init_subclass__(cls, **kwargs: Any) -> None:
        super().__pydantic_init_subclass__(**kwargs)
        if cls.name:
            EFFECT_TYPES[cls.name] = cls
            if not cls.main:
                cls.main = next(iter(cls.model_fields))

    @classmethod
    def admissible(cls, params: dict[str, float]) -> bool:
        """Physically admissible values: a parameter the vocabulary bounds below by 0 (a friction, a drag) is > 0."""
        return all(params.get(k, 0.0) > 0 for k, f in cls.model_fields.items() if _lower_bound(f) == 0)


def _lower_bound(field: Any) -> float | None:
    return next((m.ge for m in field.metadata if getattr(m, "ge", None) is not None), None)


class JointTorque(_Effect):
    """An effect that is a torque on one joint, linear in its parameters: τ = Σ_i p_i · basis_i(x) with x = (θ, θ̇, φ,
    φ̇). Such an effect is one class: the simulator adds ``torque`` to its row of eq. 4 (sim.simulator), diagnose
    regresses its row's residual on ``basis`` (diagnose.regression.library) — nothing else needs to know it."""

    @staticmethod
    def basis(theta: Any, theta_dot: Any, phi: Any, phi_dot: Any) -> tuple[Any, ...]:
        """The torque per unit of each parameter (in field order), at scalar or array states."""
        raise NotImplementedError

    def torque(self, theta: Any, theta_dot: Any, phi: Any, phi_dot: Any) -> Any:
        """The torque on its joint (N m) at the states."""
        values = self.model_dump().values()
        return sum(p * b for p, b in zip(values, self.basis(theta, theta_dot, phi, phi_dot), strict=True))


class ArmCoulomb(_Effect):
    name = "arm_coulomb"
    lookalikes = ("input_deadzone",)
    experiments = {"input_deadzone": (
        "a slow constant-velocity arm sweep (Coulomb friction needs the torque Fc at any speed, a deadzone lets "
        "the arm coast with |u| below the width) or a dither on u (it smooths a deadzone, not friction)")}
    Fc: float = Field(ge=0, description="sliding friction torque on the arm, N m")


class ArmViscous(_Effect):
    name = "arm_viscous"
    experiments = {"arm_coulomb": (
        "runs at several arm speeds in both directions (viscous friction grows with the speed, Coulomb friction does "
        "not; on one speed in one direction the two are the same constant torque)")}
    Fv: float = Field(ge=0, description="viscous friction on the arm, N m s/rad")


class ArmStiction(_Effect):
    name = "arm_stiction"
    Fs: float = Field(ge=0, description="breakaway torque of the arm, N m")


class ArmLuGre(_Effect):
    name = "arm_lugre"
    main = "Fs"
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
    name = "pendulum_viscous"
    equation = PEND
    lookalikes = ("pendulum_coulomb",)
    experiments = {"pendulum_coulomb": (
        "a pendulum free decay from a large angle (viscous damping: exponential envelope; Coulomb: linear)")}
    bp: float = Field(ge=0, description="viscous friction at the pendulum pivot, N m s/rad")


class PendulumCoulomb(_Effect):
    name = "pendulum_coulomb"
    equation = PEND
    lookalikes = ("pendulum_viscous",)
    Fc: float = Field(ge=0, description="Coulomb friction at the pendulum pivot, N m")


class ThetaOffset(_Effect):
    name = "theta_offset"
    equation = PEND
    lookalikes = ("arm_spring", "arm_bias")
    offset: float = Field(description="rad the θ sensor adds to the true θ")


class InputDelay(_Effect):
    name = "input_delay"
    delay: float = Field(ge=0, le=0.5, description="transport delay of the actuator command, s")


class InputDeadzone(_Effect):
    name = "input_deadzone"
    lookalikes = ("arm_coulomb",)
    width: float = Field(ge=0, description="half-width of the dead band, N m")


class InputGain(_Effect):
    name = "input_gain"
    lookalikes = ("arm_inertia", "arm_bias")
    experiments = {
        "arm_inertia": (
            "a static torque test (a known command with the arm held against a force gauge measures the gain alone) "
            "or a repeat with a known inertia added to the arm"),
        "arm_bias": (
            "a command that changes while the arm moves (several step levels, a sine) or a rest at zero command: on "
            "one constant step the gain's extra torque and a constant one are the same column; at rest a bias moves "
            "the arm"),
    }
    gain: float = Field(gt=0, description="actual torque per commanded torque")


class InputSaturation(_Effect):
    name = "input_saturation"
    limit: float = Field(gt=0, description="largest torque the actuator delivers, N m")


class ArmSpring(_Effect):
    name = "arm_spring"
    lookalikes = ("theta_offset", "arm_inertia")
    experiments = {
        "arm_inertia": (
            "an arm excitation with more than one frequency (a chirp, steps, or a second sine): a spring's torque "
            "follows φ − φ0 and an inertia's φ̈, which on a single frequency are the same column (k = −ΔJ·ω²)"),
        "theta_offset": (
            "a pendulum free decay (it comes to rest hanging at θ = π + offset: a sensor offset shows there, a cable "
            "spring does not) and a slow arm sweep (a spring needs the torque k(φ − φ0))"),
    }
    k: float = Field(ge=0, description="cable stiffness on the arm, N m/rad")
    phi0: float = Field(default=0.0, description="arm angle where the cable is relaxed, rad")


class ArmInertia(_Effect):
    name = "arm_inertia"
    lookalikes = ("input_gain", "arm_spring")
    J: float = Field(gt=0, description="the arm's actual inertia J (thesis parametrisation), kg m²")


class ArmBias(_Effect):
    name = "arm_bias"
    lookalikes = ("theta_offset", "input_gain")
    tau: float = Field(description="constant torque on the arm, N m (cable drag, driver offset, tilted base)")


class CommandLatency(_Effect):
    name = "command_latency"
    delay: float = Field(ge=0, le=0.5, description="total s from the sample instant to the torque acting "
                         "(replaces command_delay_ticks·h + input_delay)")


class ArmAirDrag(JointTorque):
    """Air drag on the turning arm: each element of the arm at radius r moves at r·φ̇ through still air and meets the
    force ½ρC_d·(r·φ̇)² dA against its motion, so the arm meets the torque −c·φ̇|φ̇|, c = ½ρC_d ∫ r³ w(r) dr (w: the
    arm's frontal width at r) — quadratic in the speed, where viscous friction is linear."""

    name = "arm_air_drag"
    lookalikes = ("arm_viscous",)
    # Not in the default search: on balancing data its column trades with the arm inertia and the input gain (a
    # realistic case's gain 0.7 came out 0.87 with it among the candidates), so diagnose tries it when asked.
    searched = False
    experiments = {"arm_viscous": (
        "runs at two or more arm speeds (air drag grows as φ̇², viscous friction as φ̇; over one speed range the two "
        "are nearly one column)")}
    c: float = Field(ge=0, description="air-drag coefficient of the arm, N m s²/rad²")

    @staticmethod
    def basis(theta: Any, theta_dot: Any, phi: Any, phi_dot: Any) -> tuple[Any, ...]:
        return (-phi_dot * abs(phi_dot),)


# A new effect is one class above this line (a JointTorque when it is a torque on a joint, linear in its parameters).


class _EffectSet(_Effect):
    """A set of named effects (one optional field per registered effect); absent ones are not in the physics."""

    @model_validator(mode="after")
    def _consistent(self) -> _EffectSet:
        lugre, coulomb, stiction = (getattr(self, n) for n in ("arm_lugre", "arm_coulomb", "arm_stiction"))
        if lugre is not None and (coulomb or stiction):
            raise ValueError("arm_lugre already contains Coulomb and stiction; do not combine it with them")
        if stiction is not None:
            fc = coulomb.Fc if coulomb else 0.0
            if stiction.Fs < fc:
                raise ValueError("arm_stiction.Fs (breakaway) must be >= arm_coulomb.Fc (sliding)")
        return self

    def present(self) -> dict[str, dict[str, float]]:
        """{name: params} of the effects that are set, in the diagnose JSON shape."""
        return {
            name: getattr(self, name).model_dump()
            for name in EFFECT_TYPES
            if getattr(self, name) is not None
        }

    def joint_torques(self) -> tuple[JointTorque, ...]:
        """The effects that are set and are torques on a joint (JointTorque), in registry order."""
        return tuple(e for name in EFFECT_TYPES if isinstance(e := getattr(self, name), JointTorque))

    def merged(self, other: Effects | dict[str, Any]) -> Effects:
        """These effects with ``other``'s set on top (other wins per effect)."""
        data = self.present()
        extra = other.present() if isinstance(other, _EffectSet) else other
        data.update(extra)
        return Effects.model_validate(data)


Effects = create_model(  # type: ignore[call-overload]
    "Effects", __base__=_EffectSet, __module__=__name__,
    **{name: (cls | None, None) for name, cls in EFFECT_TYPES.items()},
)


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
