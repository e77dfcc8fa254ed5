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

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, create_model, model_validator

from furuta_rt.model.friction import Coulomb, Viscous, law_on_array

ARM, PEND = "arm", "pendulum"  # the rows of eq. 4 an effect can act in
PENDULUM_COULOMB_EPSILON = 0.01  # rad/s: pendulum-pivot Coulomb friction uses eq. 1's smoothed transition

EFFECT_TYPES: dict[str, type[Effect]] = {}
"""The effect registry: every effect class by its name, in definition order. A class registers itself by naming
itself (``name = "..."``); the rig configuration (Effects), the rig model and simulator (joint torques), hil_mock and
diagnose's regression library all read this one table. Its order is the order diagnose tries the effects in."""


class Effect(BaseModel):
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
    regressed: ClassVar[bool] = True  # a candidate of diagnose's regression (False: another stage measures it)
    # How diagnose's regression sees it (``ctx``: diagnose.regression.library.Context, one recording's residuals;
    # ``path``: its InputPath, the command path's nonlinear parameters):
    nonlinear: ClassVar[str | None] = None  # the nonlinear parameter it moves, profiled on a grid: "delay", "latency",
    # "deadzone", "limit" (the command path), "inertia" (ΔJ), "vs" (the Stribeck speed); None: linear only
    requires: ClassVar[str | None] = None  # an effect that must be in the model first
    excludes: ClassVar[tuple[str, ...]] = ()  # effects it cannot join (the same parameter, or the same column)
    varying: ClassVar[bool] = False  # its columns change with the command path or the Stribeck speed (not cached)
    on_command: ClassVar[bool] = False  # it acts on the command (gain, delay, dead band, limit): tried only where there
    # is one (a recording without a command cannot show it)

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

    @classmethod
    def columns(cls, ctx: Any, path: Any, vs: float) -> np.ndarray:
        """(n, k) regressors of its linear parameters: the residual of its row of eq. 4 per unit departure of each,
        through the row's kernel (k = 0: it enters through its nonlinear parameter only)."""
        return np.zeros((ctx.prep.n, 0))

    @classmethod
    def from_fit(cls, coef: np.ndarray, ctx: Any, path: Any, gain: float, d_inertia: float) -> dict[str, float]:
        """Its SI parameters from the fitted coefficients, as totals: the rig's own value (if it has the effect) plus
        the departure the data asks for; ``gain``: the total input gain, ``d_inertia``: the fitted ΔJ."""
        return {p: ctx.known_value(cls.name, p) + float(c) for p, c in zip(cls.model_fields, coef, strict=True)}

    @classmethod
    def plausible(cls, par: dict[str, float], rig: Any, travel: tuple[float, float] | None) -> bool:
        """Physically admissible fitted values (``rig``: the RigConfig, ``travel``: the arm's lowest and highest angle
        in the recording, or None): by default the sign rule of ``admissible``."""
        return cls.admissible(par)


def _lower_bound(field: Any) -> float | None:
    return next((m.ge for m in field.metadata if getattr(m, "ge", None) is not None), None)


class JointTorque(Effect):
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

    @classmethod
    def columns(cls, ctx: Any, path: Any, vs: float) -> np.ndarray:
        return ctx.joint_torque_columns(cls)


class ArmCoulomb(Effect):
    name = "arm_coulomb"
    lookalikes = ("input_deadzone",)
    experiments = {"input_deadzone": (
        "a slow constant-velocity arm sweep (Coulomb friction needs the torque Fc at any speed, a deadzone lets "
        "the arm coast with |u| below the width) or a dither on u (it smooths a deadzone, not friction)")}
    Fc: float = Field(ge=0, description="sliding friction torque on the arm, N m")

    @classmethod
    def columns(cls, ctx: Any, path: Any, vs: float) -> np.ndarray:
        # the direction from the encoder counts (a smoothed speed changes sign late), then through the arm kernel
        return ctx.arm.smooth(law_on_array(Coulomb(1.0).torque, ctx.arm_direction))[:, None]


class ArmStiction(Effect):
    name = "arm_stiction"
    regressed = False  # a breakaway shows where the arm sticks, which the regression's sliding rows leave out:
    # diagnose measures it on the stick windows (diagnose.stages.stickslip)
    Fs: float = Field(ge=0, description="breakaway torque of the arm, N m")


class ArmViscous(Effect):
    name = "arm_viscous"
    experiments = {"arm_coulomb": (
        "runs at several arm speeds in both directions (viscous friction grows with the speed, Coulomb friction does "
        "not; on one speed in one direction the two are the same constant torque)")}
    Fv: float = Field(ge=0, description="viscous friction on the arm, N m s/rad")

    @classmethod
    def columns(cls, ctx: Any, path: Any, vs: float) -> np.ndarray:
        return Viscous(1.0).torque(ctx.arm.phi_dot)[:, None]


class ArmSpring(Effect):
    name = "arm_spring"
    lookalikes = ("theta_offset", "arm_inertia")
    excludes = ("arm_bias",)  # its constant part k·φ0 is arm_bias's column
    experiments = {
        "arm_inertia": (
            "an arm excitation with more than one frequency (a chirp, steps, or a second sine): a spring's torque "
            "follows φ − φ0 and an inertia's φ̈, which on a single frequency are the same column (k = −ΔJ·ω²)"),
        "theta_offset": (
            "a pendulum free decay (it comes to rest hanging at θ = π + offset: a sensor offset shows there, a cable "
            "spring does not) and a slow arm sweep (a spring needs the torque k(φ − φ0))"),
    }
    MAX_TRAVEL: ClassVar[float] = 2 * np.pi  # rad: an arm that turns a whole revolution cannot be tied by a cable
    k: float = Field(ge=0, description="cable stiffness on the arm, N m/rad")
    phi0: float = Field(default=0.0, description="arm angle where the cable is relaxed, rad")

    @classmethod
    def columns(cls, ctx: Any, path: Any, vs: float) -> np.ndarray:
        return np.column_stack([-ctx.arm.phi, np.ones(ctx.prep.n)])  # −k(φ − φ0) = −k·φ + (k φ0)

    @classmethod
    def from_fit(cls, coef: np.ndarray, ctx: Any, path: Any, gain: float, d_inertia: float) -> dict[str, float]:
        k0, phi00 = ctx.known_value(cls.name, "k"), ctx.known_value(cls.name, "phi0")
        kk = k0 + float(coef[0])
        return {"k": kk, "phi0": (k0 * phi00 + float(coef[1])) / kk if kk != 0 else 0.0}

    @classmethod
    def plausible(cls, par: dict[str, float], rig: Any, travel: tuple[float, float] | None) -> bool:
        """A restoring spring; with the arm's travel, only on an arm whose travel allows a cable (less than a turn),
        relaxed inside that travel."""
        if travel is None:
            return par["k"] > 0 and abs(par["phi0"]) < 2 * np.pi
        lo, hi = travel
        return par["k"] > 0 and hi - lo < cls.MAX_TRAVEL and lo <= par["phi0"] <= hi


class ArmBias(Effect):
    name = "arm_bias"
    lookalikes = ("theta_offset", "input_gain")
    excludes = ("arm_spring",)
    tau: float = Field(description="constant torque on the arm, N m (cable drag, driver offset, tilted base)")

    @classmethod
    def columns(cls, ctx: Any, path: Any, vs: float) -> np.ndarray:
        return np.ones((ctx.prep.n, 1))  # a constant torque (the kernel integrates to one)


class ArmInertia(Effect):
    name = "arm_inertia"
    lookalikes = ("input_gain", "arm_spring")
    nonlinear = "inertia"
    J: float = Field(gt=0, description="the arm's actual inertia J (thesis parametrisation), kg m²")

    @classmethod
    def from_fit(cls, coef: np.ndarray, ctx: Any, path: Any, gain: float, d_inertia: float) -> dict[str, float]:
        return {"J": float(ctx.base_inertia + d_inertia)}

    @classmethod
    def plausible(cls, par: dict[str, float], rig: Any, travel: tuple[float, float] | None) -> bool:
        return par["J"] > 0.05 * rig.plant.arm_inertia


class InputGain(Effect):
    name = "input_gain"
    on_command = True
    lookalikes = ("arm_inertia", "arm_bias")
    varying = True
    experiments = {
        "arm_inertia": (
            "a static torque test (a known command with the arm held against a force gauge measures the gain alone) "
            "or a repeat with a known inertia added to the arm"),
        "arm_bias": (
            "a command that changes while the arm moves (several step levels, a sine) or a rest at zero command: on "
            "one constant step the gain's extra torque and a constant one are the same column; at rest a bias moves "
            "the arm"),
    }
    # any positive factor a datasheet or a drive mode may be off by (a driver's gain, a current or velocity mode, a
    # command in per-unit rather than volts); the sign is diagnose.stages.conventions' business
    MIN: ClassVar[float] = 1e-3
    MAX: ClassVar[float] = 1e4
    gain: float = Field(gt=0, description="actual torque per commanded torque")

    @classmethod
    def columns(cls, ctx: Any, path: Any, vs: float) -> np.ndarray:
        return ctx.command_torque(path)[:, None]

    @classmethod
    def from_fit(cls, coef: np.ndarray, ctx: Any, path: Any, gain: float, d_inertia: float) -> dict[str, float]:
        return {"gain": float(ctx.known_gain * (1.0 + coef[0]))}

    @classmethod
    def plausible(cls, par: dict[str, float], rig: Any, travel: tuple[float, float] | None) -> bool:
        return cls.MIN < par["gain"] < cls.MAX


class InputDelay(Effect):
    name = "input_delay"
    on_command = True
    nonlinear = "delay"
    excludes = ("command_latency",)
    delay: float = Field(ge=0, le=0.5, description="transport delay of the actuator command, s")

    @classmethod
    def from_fit(cls, coef: np.ndarray, ctx: Any, path: Any, gain: float, d_inertia: float) -> dict[str, float]:
        return {"delay": float(path.delay)}


class CommandLatency(Effect):
    name = "command_latency"
    nonlinear = "latency"
    excludes = ("input_delay",)
    delay: float = Field(ge=0, le=0.5, description="total s from the sample instant to the torque acting "
                         "(replaces command_delay_ticks·h + input_delay)")

    @classmethod
    def from_fit(cls, coef: np.ndarray, ctx: Any, path: Any, gain: float, d_inertia: float) -> dict[str, float]:
        return {"delay": float(ctx.prep.command_lag + path.delay)}  # the total: command_delay_ticks·h + path's delay

    @classmethod
    def plausible(cls, par: dict[str, float], rig: Any, travel: tuple[float, float] | None) -> bool:
        """Shorter than the rig's own latency (a longer one is an input_delay on top of it), and causal: an optimum
        more than half a tick below 0 is something else that a lead would mimic."""
        nominal = total_latency(rig.effects, rig.control.command_delay_ticks, rig.control.rate_hz)
        return -0.5 / rig.control.rate_hz <= par["delay"] < nominal


class InputDeadzone(Effect):
    name = "input_deadzone"
    on_command = True
    lookalikes = ("arm_coulomb",)
    nonlinear = "deadzone"
    width: float = Field(ge=0, description="half-width of the dead band, N m")

    @classmethod
    def from_fit(cls, coef: np.ndarray, ctx: Any, path: Any, gain: float, d_inertia: float) -> dict[str, float]:
        return {"width": float(path.deadzone * gain)}

    @classmethod
    def plausible(cls, par: dict[str, float], rig: Any, travel: tuple[float, float] | None) -> bool:
        return True  # judged by its kinks (commands on both sides of its edge), not by its sign


class InputSaturation(Effect):
    name = "input_saturation"
    on_command = True
    nonlinear = "limit"
    limit: float = Field(gt=0, description="largest torque the actuator delivers, N m")

    @classmethod
    def from_fit(cls, coef: np.ndarray, ctx: Any, path: Any, gain: float, d_inertia: float) -> dict[str, float]:
        return {"limit": float((path.limit or 0.0) * gain)}


class ArmLuGre(Effect):
    name = "arm_lugre"
    main = "Fs"
    nonlinear = "vs"
    requires = "arm_coulomb"  # its Stribeck peak sits on arm_coulomb's sliding level
    varying = True
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

    @classmethod
    def columns(cls, ctx: Any, path: Any, vs: float) -> np.ndarray:
        return ctx.stribeck(vs)[:, None]

    @classmethod
    def from_fit(cls, coef: np.ndarray, ctx: Any, path: Any, gain: float, d_inertia: float) -> dict[str, float]:
        return {"Fs_minus_Fc": float(coef[0])}  # the Stribeck peak; Context.lugre_params completes it with Fc, Fv

    @classmethod
    def plausible(cls, par: dict[str, float], rig: Any, travel: tuple[float, float] | None) -> bool:
        return par.get("Fs_minus_Fc", par.get("Fs", 0.0) - par.get("Fc", 0.0)) > 0


class PendulumViscous(Effect):
    name = "pendulum_viscous"
    equation = PEND
    lookalikes = ("pendulum_coulomb",)
    experiments = {"pendulum_coulomb": (
        "a pendulum free decay from a large angle (viscous damping: exponential envelope; Coulomb: linear)")}
    bp: float = Field(ge=0, description="viscous friction at the pendulum pivot, N m s/rad")

    @classmethod
    def columns(cls, ctx: Any, path: Any, vs: float) -> np.ndarray:
        return Viscous(1.0).torque(ctx.pend.theta_dot)[:, None]


class PendulumCoulomb(Effect):
    name = "pendulum_coulomb"
    equation = PEND
    lookalikes = ("pendulum_viscous",)
    Fc: float = Field(ge=0, description="Coulomb friction at the pendulum pivot, N m")

    @classmethod
    def columns(cls, ctx: Any, path: Any, vs: float) -> np.ndarray:
        law = Coulomb(1.0, PENDULUM_COULOMB_EPSILON).torque
        return ctx.pend.product(law_on_array(law, ctx.fine.theta_dot))[:, None]


class ThetaOffset(Effect):
    name = "theta_offset"
    equation = PEND
    lookalikes = ("arm_spring", "arm_bias")
    offset: float = Field(description="rad the θ sensor adds to the true θ")

    @classmethod
    def columns(cls, ctx: Any, path: Any, vs: float) -> np.ndarray:
        h = 1e-4  # ∂ID_pend/∂offset by a central difference of eq. 4's inverse dynamics
        up, down = ctx.inverse_dynamics(PEND, theta_shift=-h), ctx.inverse_dynamics(PEND, theta_shift=h)
        return ((up - down) / (2 * h))[:, None]

    @classmethod
    def plausible(cls, par: dict[str, float], rig: Any, travel: tuple[float, float] | None) -> bool:
        return abs(par["offset"]) < 0.3


class ArmAirDrag(JointTorque):
    """Air drag on the turning arm: each element of the arm at radius r moves at r·φ̇ through still air and meets the
    force ½ρC_d·(r·φ̇)² dA against its motion, so the arm meets the torque −c·φ̇|φ̇|, c = ½ρC_d ∫ r³ w(r) dr (w: the
    arm's frontal width at r) — quadratic in the speed, where viscous friction is linear."""

    name = "arm_air_drag"
    lookalikes = ("arm_viscous",)
    # Not in the default search: on balancing data (one band of arm speeds, the gain and inertia free) φ̇|φ̇| is nearly
    # a combination of the input gain's and the arm inertia's columns, so among the default candidates it would take
    # part of their size; diagnose tries it when asked.
    searched = False
    experiments = {"arm_viscous": (
        "runs at two or more arm speeds (air drag grows as φ̇², viscous friction as φ̇; over one speed range the two "
        "are nearly one column)")}
    c: float = Field(ge=0, description="air-drag coefficient of the arm, N m s²/rad²")

    @staticmethod
    def basis(theta: Any, theta_dot: Any, phi: Any, phi_dot: Any) -> tuple[Any, ...]:
        return (-phi_dot * abs(phi_dot),)


# A new effect is one class above this line: a JointTorque when it is a torque on a joint, linear in its parameters
# (nothing else to write); otherwise its regression hooks (columns, from_fit, plausible, nonlinear) say how it enters
# diagnose's residual, and its place in the class list is its place in diagnose's search.


def command_timing(command_delay_ticks: int, input_delay: float, command_latency: float | None) -> tuple[int, float]:
    """The latency rule (the module docstring), as (whole control periods the driver holds the command after its
    sample, seconds of the actuator's delay line after that): command_delay_ticks and ``input_delay``, or 0 and the
    whole ``command_latency`` when the rig has one. The total from the sample instant is ticks·h + delay. The
    simulator's delay line, its command path, diagnose's window simulations and its nominal model all read it."""
    if command_latency is not None:
        return 0, command_latency
    return command_delay_ticks, input_delay


def total_latency(effects: Effects, command_delay_ticks: int, rate_hz: float) -> float:
    """Seconds from the sample instant to the torque acting for a rig with ``effects`` (command_timing's total)."""
    ticks, delay = command_timing(command_delay_ticks, effects.input_delay.delay if effects.input_delay else 0.0,
                                  effects.command_latency.delay if effects.command_latency else None)
    return ticks / rate_hz + delay


def latency_effect(total: float, command_lag: float) -> tuple[str, float]:
    """The rule inverted: the effect that carries a total latency ``total`` (s) on a rig whose driver holds the
    command ``command_lag`` = command_delay_ticks·h, and its delay: an ``input_delay`` of total − command_lag when
    longer, else a ``command_latency`` of the total."""
    on_top = total - command_lag
    return ("input_delay", on_top) if on_top > 0 else ("command_latency", total)


class _EffectSet(Effect):
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
            for name in type(self).model_fields
            if getattr(self, name) is not None
        }

    def joint_torques(self) -> tuple[JointTorque, ...]:
        """The effects that are set and are torques on a joint (JointTorque), in registry order."""
        return tuple(e for name in type(self).model_fields if isinstance(e := getattr(self, name), JointTorque))

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
