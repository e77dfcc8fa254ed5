"""Rig configuration: pydantic models read from TOML.

A rig file describes the hardware (plant parameters, actuator, sensor path, DAQ calibration), the
controller (rate, gain design, compensation, observer), the safety limits, and the physics known
beyond eq. 4 (``[effects]``, see furuta_rt.model.effects). Shipped rigs live in furuta_rt/rigs/.
"""

from __future__ import annotations

import difflib
import math
from pathlib import Path
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from furuta_rt.errors import UserError
from furuta_rt.model.effects import Effects
from furuta_rt.model.parameters import G, LumpedParameters
from furuta_rt.tomlfile import read_toml

Positive = Annotated[float, Field(gt=0)]
NonNegative = Annotated[float, Field(ge=0)]

class _Section(BaseModel):
    # NaN and ±inf are valid TOML floats; no key of a rig means them
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class PlantConfig(_Section):
    """Eq. 4 parameters, given in one of three parametrisations.

    thesis (appendix C): l, r, M, m, Jp, J.  general (Cazzolato & Prime 2011): m1, l1, L1, J1, m2, l2,
    L2, J2.  lumped: alpha, beta, gamma, epsilon directly.
    """

    parametrisation: Literal["thesis", "general", "lumped"] = "thesis"
    g: Positive = G
    # thesis
    l: Positive | None = None
    r: Positive | None = None
    M: NonNegative | None = None
    m: NonNegative | None = None
    Jp: Positive | None = None
    J: Positive | None = None
    # general
    m1: NonNegative | None = None
    l1: NonNegative | None = None
    L1: Positive | None = None
    J1: NonNegative | None = None
    m2: Positive | None = None
    l2: Positive | None = None
    L2: Positive | None = None
    J2: NonNegative | None = None
    # lumped
    alpha: Positive | None = None
    beta: Positive | None = None
    gamma: NonNegative | None = None
    epsilon: Positive | None = None

    _REQUIRED = {
        "thesis": ("l", "r", "M", "m", "Jp", "J"),
        "general": ("m1", "l1", "L1", "J1", "m2", "l2", "J2"),
        "lumped": ("alpha", "beta", "gamma", "epsilon"),
    }

    @model_validator(mode="after")
    def _complete(self) -> PlantConfig:
        missing = [k for k in self._REQUIRED[self.parametrisation] if getattr(self, k) is None]
        if missing:
            raise ValueError(f"parametrisation '{self.parametrisation}' needs {', '.join(missing)}")
        self.lumped()  # positivity of the mass matrix
        return self

    def lumped(self) -> LumpedParameters:
        """α, β, γ, ε for this plant."""
        if self.parametrisation == "thesis":
            return LumpedParameters.from_thesis(
                l=self.l, r=self.r, M=self.M, m=self.m, Jp=self.Jp, J=self.J, g=self.g  # type: ignore[arg-type]
            )
        if self.parametrisation == "general":
            return LumpedParameters.from_general(
                m1=self.m1, l1=self.l1, L1=self.L1, J1=self.J1,  # type: ignore[arg-type]
                m2=self.m2, l2=self.l2, J2=self.J2, g=self.g,  # type: ignore[arg-type]
            )
        return LumpedParameters(self.alpha, self.beta, self.gamma, self.epsilon)  # type: ignore[arg-type]

    @property
    def arm_inertia(self) -> float:
        """The arm's own inertia in this parametrisation (J, or J1 + m1 l1² for 'general')."""
        if self.parametrisation == "thesis":
            return float(self.J)  # type: ignore[arg-type]
        if self.parametrisation == "general":
            return float(self.J1 + self.m1 * self.l1**2)  # type: ignore[operator]
        return float(self.beta)  # type: ignore[arg-type]


class ActuatorConfig(_Section):
    kind: Literal["torque", "dc_motor"] = "torque"
    limit: Positive = Field(default=2.0, description="command saturation, N m (torque) or V (dc_motor)")
    Kt: Positive | None = None
    R: Positive | None = None
    Ke: NonNegative | None = None

    @model_validator(mode="after")
    def _motor(self) -> ActuatorConfig:
        if self.kind == "dc_motor" and None in (self.Kt, self.R, self.Ke):
            raise ValueError("kind 'dc_motor' needs Kt, R and Ke")
        return self


class SensorConfig(_Section):
    bessel_cutoff: Positive | None = Field(
        default=50.0, description='−3 dB of the θ filter, rad/s; "none" = θ measured directly (an encoder)'
    )
    encoder_counts_per_rev: Annotated[int, Field(gt=0)] = 4096
    theta_rad_per_count: Positive = 2.0 * math.pi / 65536.0
    theta_dot_rad_s_per_count: Positive = 100.0 / 65536.0
    theta_noise: NonNegative = Field(default=2e-4, description="white noise std at the θ ADC, rad")
    theta_dot_noise: NonNegative = Field(default=2e-3, description="white noise std at the θ̇ ADC, rad/s")
    theta_wraps: bool = Field(
        default=False, description="θ's sensor reads the full turn and the DAQ reports θ modulo its range (an "
        "encoder, a 360° angle sensor); false: the θ ADC saturates at its rail with ADC_OVERRANGE"
    )

    @field_validator("bessel_cutoff", mode="before")
    @classmethod
    def _none_filter(cls, value: object) -> object:
        """TOML has no null: ``bessel_cutoff = "none"`` means no analog θ filter."""
        return None if isinstance(value, str) and value.strip().lower() == "none" else value


class PolePlacement(_Section):
    omega1: Positive = 3.0
    omega2: Positive = 7.0
    zeta1: Positive = 0.7
    zeta2: Positive = 0.7


class LQRWeights(_Section):
    Q: Annotated[list[NonNegative], Field(min_length=4, max_length=4)] = [100.0, 1.0, 10.0, 1.0]
    R: Positive = 10.0


class ControlConfig(_Section):
    rate_hz: Annotated[float, Field(gt=0, le=20000)] = 500.0
    design: Literal["pole_placement", "lqr", "gains"] = "pole_placement"
    pole_placement: PolePlacement = PolePlacement()
    lqr: LQRWeights = LQRWeights()
    gains: Annotated[list[float], Field(min_length=4, max_length=4)] | None = None
    command_delay_ticks: Annotated[int, Field(ge=0, le=10)] = Field(
        default=1, description="ticks between a SAMPLE and the tick its COMMAND takes effect"
    )

    @model_validator(mode="after")
    def _gains(self) -> ControlConfig:
        if self.design == "gains" and self.gains is None:
            raise ValueError("design 'gains' needs gains = [l1, l2, l3, l4]")
        return self


class CoulombComp(_Section):
    Fc: NonNegative = 0.0
    epsilon: NonNegative = 0.05
    Fv: NonNegative = Field(default=0.0, description="viscous part compensated as well, N m s/rad")


class StictionComp(_Section):
    Fc: NonNegative = 0.0
    Fs: NonNegative = 0.0
    v_zero: NonNegative = 0.02
    Fv: NonNegative = Field(default=0.0, description="viscous part compensated as well, N m s/rad")


class LuGreComp(_Section):
    sigma0: Positive = 50.0
    sigma1: NonNegative = 1.0
    Fc: NonNegative = 0.0
    Fs: NonNegative = 0.0
    vs: Positive = 0.1
    Fv: NonNegative = 0.0


class AdaptiveComp(_Section):
    """Adaptive Coulomb compensation (furuta_rt.controller.compensation.AdaptiveCoulomb)."""

    Fc0: NonNegative = Field(default=0.0, description="initial Coulomb estimate, N m")
    Fc_max: Positive = Field(default=1.5, description="upper bound of the estimate, N m")
    time_constant: Positive = Field(default=0.5, description="convergence time constant while the arm slides, s")
    epsilon: NonNegative = Field(default=0.01, description="ε of eq. 1 in the applied compensation, rad/s")
    v_min: Positive = Field(default=0.05, description="mean |φ̇| over a window below which it is frozen, rad/s")
    window_ticks: Annotated[int, Field(ge=1, le=5000)] = Field(
        default=25, description="the estimate moves once per window of this many ticks of sliding one way")


CompMode = Literal["none", "coulomb", "stiction", "lugre", "adaptive"]
COMP_MODES: tuple[str, ...] = ("none", "coulomb", "stiction", "lugre", "adaptive")


class CompensationConfig(_Section):
    mode: CompMode = "none"
    coulomb: CoulombComp = CoulombComp()
    stiction: StictionComp = StictionComp()
    lugre: LuGreComp = LuGreComp()
    adaptive: AdaptiveComp = AdaptiveComp()


class ObserverConfig(_Section):
    accel_noise: Positive = Field(default=10.0, description="std of unmodelled arm acceleration, rad/s²")
    phi_noise: Positive | None = Field(default=None, description="std of φ measurement, rad (default: encoder LSB/√12)")


class SafetyConfig(_Section):
    theta_limit: Positive = 0.5
    phi_limit: Positive = 6.0 * math.pi
    arm_theta: Positive = Field(default=0.1, description="|θ| below which arming is allowed, rad")
    link_loss_periods: Annotated[int, Field(ge=1)] = 2
    max_consecutive_overruns: Annotated[int, Field(ge=1)] = 5


class SwingUpConfig(_Section):
    """Energy swing-up from hanging (Åström & Furuta 2000) and the catch into balancing (furuta_rt.controller.swingup).
    A key left out (None) is derived from the model there."""

    enabled: bool = Field(default=False, description="swing up from hanging before balancing (run --swing-up)")
    accel_max: Positive | None = Field(default=None, description="arm acceleration of the energy pump, rad/s²")
    energy_gain: Positive | None = Field(default=None, description="arm acceleration per J of missing energy, rad/s² per J")
    energy_margin: Annotated[float, Field(ge=0.0, le=0.5)] = Field(
        default=0.02, description="energy aimed at above the upright one, as a fraction of 2ε (friction losses)")
    arm_omega: Positive | None = Field(default=None, description="natural frequency of the arm centring, rad/s")
    arm_damping: Positive | None = Field(default=None, description="arm acceleration per arm speed, 1/s")
    catch_theta: Positive | None = Field(default=None, description="|θ| below which balancing takes over, rad")
    catch_energy: Positive = Field(default=0.1, description="|E − E_up| below which balancing takes over, × 2ε")
    fall_theta: Positive | None = Field(default=None, description="|θ| beyond which balancing has lost it, rad "
                                        "(default safety.theta_limit)")
    arm_return_s: Positive = Field(default=1.0, description="after the catch, the arm's reference goes from where "
                                   "it was caught back to 0 with this time constant, s")
    on_fall: Literal["swing_up", "trip"] = Field(default="swing_up", description="after a fall: swing up again or trip")
    calibration_s: Annotated[float, Field(gt=0.0, le=10.0)] = Field(
        default=1.0, description="seconds the pendulum must hang still for the start-up calibration")
    still_theta: Positive = Field(default=0.02, description="largest θ spread over the calibration window, rad")
    hanging_tolerance: Positive = Field(default=0.3, description="largest distance of the hanging reading from π, rad")


class RigConfig(_Section):
    name: str = "thesis"
    description: str = ""
    plant: PlantConfig
    actuator: ActuatorConfig = ActuatorConfig()
    sensors: SensorConfig = SensorConfig()
    control: ControlConfig = ControlConfig()
    compensation: CompensationConfig = CompensationConfig()
    observer: ObserverConfig = ObserverConfig()
    safety: SafetyConfig = SafetyConfig()
    swing_up: SwingUpConfig = SwingUpConfig()
    effects: Effects = Effects()

    def lumped(self) -> LumpedParameters:
        return self.plant.lumped()


SHIPPED_RIGS = ("thesis", "qube_servo2", "macstepien")

# Plausibility of the plant's sizes: what a Furuta pendulum on a table or a lab bench can be. A value
# beyond them is almost always a unit mistake (cm or mm typed as m, g as kg), which would otherwise arm
# and trip, or design gains for a machine that does not exist.
MAX_LENGTH_M = 2.0
MAX_MASS_KG = 5.0
MAX_INERTIA_KG_M2 = MAX_MASS_KG * MAX_LENGTH_M**2
EARTH_G = (9.76, 9.84)  # m/s², equator to pole, sea level to high mountains
_BOUNDS: tuple[tuple[tuple[str, ...], float, str, str, tuple[tuple[str, float], ...]], ...] = (
    (("l", "r", "l1", "L1", "l2", "L2"), MAX_LENGTH_M, "m", "link length", (("cm", 100.0), ("mm", 1000.0))),
    (("M", "m", "m1", "m2"), MAX_MASS_KG, "kg", "link mass", (("g", 1000.0),)),
    (("Jp", "J", "J1", "J2", "alpha", "beta", "gamma"), MAX_INERTIA_KG_M2, "kg m²", "inertia",
     (("kg cm²", 1e4), ("g cm²", 1e7))),
    (("epsilon",), MAX_MASS_KG * G * MAX_LENGTH_M, "N m", "gravity torque m g l", (("N cm", 100.0), ("N mm", 1000.0))),
)


# Limits and thresholds in angles, rates and torques: beyond these bounds a value is almost always typed in degrees
# (or N cm) while the key is in radians (N m): ``safety.theta_limit = 28.6`` would never trip.
MAX_TORQUE_NM = 20.0  # a Furuta arm's motor; also the largest friction a compensation may cancel
MAX_VOLTAGE_V = 60.0
MAX_RATE_RAD_S = 50.0  # rate thresholds (ε of eq. 1, stiction and Stribeck speeds): a few turns a second at most
_DEG = (("degrees", 180.0 / math.pi),)
_DEG_S = (("degrees/s", 180.0 / math.pi),)
_N_CM = (("N cm", 100.0), ("N mm", 1000.0))
_ANGLE_FROM_UPRIGHT = (math.pi, "rad", "an angle from upright (half a turn at most)", _DEG)
_LIMITS: tuple[tuple[str, float, str, str, tuple[tuple[str, float], ...]], ...] = (
    ("safety.theta_limit", *_ANGLE_FROM_UPRIGHT),
    ("safety.arm_theta", *_ANGLE_FROM_UPRIGHT),
    ("safety.phi_limit", 20 * math.pi, "rad", "an arm travel (ten turns at most)", _DEG),
    ("swing_up.catch_theta", *_ANGLE_FROM_UPRIGHT),
    ("swing_up.fall_theta", *_ANGLE_FROM_UPRIGHT),
    ("swing_up.still_theta", *_ANGLE_FROM_UPRIGHT),
    ("swing_up.hanging_tolerance", *_ANGLE_FROM_UPRIGHT),
    ("compensation.coulomb.epsilon", MAX_RATE_RAD_S, "rad/s", "a rate threshold", _DEG_S),
    ("compensation.stiction.v_zero", MAX_RATE_RAD_S, "rad/s", "a rate threshold", _DEG_S),
    ("compensation.lugre.vs", MAX_RATE_RAD_S, "rad/s", "a rate threshold", _DEG_S),
    ("compensation.adaptive.epsilon", MAX_RATE_RAD_S, "rad/s", "a rate threshold", _DEG_S),
    ("compensation.adaptive.v_min", MAX_RATE_RAD_S, "rad/s", "a rate threshold", _DEG_S),
    *((f"compensation.{key}", MAX_TORQUE_NM, "N m", "a friction torque", _N_CM) for key in (
        "coulomb.Fc", "stiction.Fc", "stiction.Fs", "lugre.Fc", "lugre.Fs", "adaptive.Fc0", "adaptive.Fc_max")),
)


def _unit_hint(value: float, limit: float, units: tuple[tuple[str, float], ...], si: str) -> str:
    for name, factor in units:
        if value / factor <= limit:
            return f"; in {name}? {value:g} {name} = {value / factor:.4g} {si}"
    return ""


def implausible(rig: RigConfig) -> list[str]:
    """Plant values no Furuta pendulum has, and angle, rate and torque limits no rig uses (almost always a unit
    mistake), one message each naming the key, the bound and the likely unit; empty when all are plausible."""
    p = rig.plant
    out = []
    for keys, limit, si, what, units in _BOUNDS:
        for key in keys:
            value = getattr(p, key)
            if value is not None and value > limit:
                out.append(f"key 'plant.{key}': {value:g} {si} is more than any Furuta pendulum's {what} "
                           f"({limit:g} {si} at most){_unit_hint(value, limit, units, si)}")
    for key, limit, si, what, units in _LIMITS:
        value = rig
        for part in key.split("."):
            value = getattr(value, part)
        if value is not None and value > limit:
            out.append(f"key '{key}': {value:g} {si} is more than {what} ({limit:g} {si} at most)"
                       f"{_unit_hint(value, limit, units, si)}")
    a = rig.actuator
    a_limit, a_unit, a_units = (MAX_VOLTAGE_V, "V", ()) if a.kind == "dc_motor" else (MAX_TORQUE_NM, "N m", _N_CM)
    if a.limit > a_limit:
        out.append(f"key 'actuator.limit': {a.limit:g} {a_unit} is more than a Furuta arm's motor takes "
                   f"({a_limit:g} {a_unit} at most){_unit_hint(a.limit, a_limit, a_units, a_unit)}")
    lo, hi = EARTH_G
    if not lo <= p.g <= hi:
        out.append(f"key 'plant.g': {p.g:g} m/s² is not the gravity on Earth ({lo:g}–{hi:g} m/s²)"
                   + _unit_hint(p.g, hi, (("cm/s²", 100.0), ("mm/s²", 1000.0)), "m/s²"))
    return out


def require_plausible(rig: RigConfig, source: str) -> RigConfig:
    """``rig``, or a UserError naming the first implausible key (for commands that design a controller or
    drive the rig from it: run, design, analyze)."""
    problems = implausible(rig)
    if problems:
        more = f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""
        raise UserError(f"{source}: {problems[0]}{more}")
    return rig


def _format_validation_error(source: str, err: ValidationError) -> str:
    errors = err.errors()
    unknown = [".".join(str(p) for p in e["loc"]) for e in errors if e["type"] == "extra_forbidden"]
    missing = [".".join(str(p) for p in e["loc"]) for e in errors if e["type"] == "missing"]
    if unknown and missing:  # a misspelt required table or key: both halves of the one mistake, in one line
        near = difflib.get_close_matches(missing[0], unknown, n=1, cutoff=0.5)
        typo = f"'{near[0]}' is not a key; did you mean '{missing[0]}'? " if near else f"unknown key(s) {unknown}; "
        rest = len(errors) - 2 if near else len(errors) - len(unknown) - 1
        more = f" (and {rest} more problem(s))" if rest > 0 else ""
        return f"{source}: {typo}'{missing[0]}' is required and missing{more}"
    first = errors[0]
    loc = ".".join(str(p) for p in first["loc"]) or "(top level)"
    msg = first["msg"].removeprefix("Value error, ")
    if first["type"] == "extra_forbidden":
        msg = "unknown key (check the spelling; see furuta_rt/rigs/thesis.toml for all keys)"
    more = f" (and {len(err.errors()) - 1} more problem(s))" if len(err.errors()) > 1 else ""
    got = first.get("input")
    got_text = f" (got {got!r})" if first["type"] != "extra_forbidden" and not isinstance(got, dict) else ""
    return f"{source}: key '{loc}': {msg}{got_text}{more}"


def rig_from_dict(data: dict, source: str = "config") -> RigConfig:
    try:
        return RigConfig.model_validate(data)
    except ValidationError as err:
        raise UserError(_format_validation_error(source, err)) from None


def load_rig(path: str | Path | None = None) -> RigConfig:
    """Load a rig from a TOML file, or a shipped rig by name (``thesis``, ``qube_servo2``, ``macstepien``).

    Raises UserError with a one-line message naming the file, key and reason.
    """
    name = "thesis" if path is None else path
    data, source = read_toml(name, kind="config file", package="furuta_rt.rigs", shipped=SHIPPED_RIGS)
    return rig_from_dict(data, source)
