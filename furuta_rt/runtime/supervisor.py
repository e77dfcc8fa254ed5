"""The safety supervisor: a pure state machine, idle → armed → balancing → tripped, or with a swing-up
idle → calibrating → swinging_up → balancing (→ swinging_up) → tripped, or for a hanging experiment
idle → armed → open_loop → tripped.

No I/O, no clock: ``step`` gets one tick's measurement and link facts and returns the state the
tick runs in. The loop obeys it: only ``balancing`` drives the actuator; every other state sends
u = 0 with ENABLE clear, and ``tripped`` ends the run (the reason is kept and logged).

    idle       waiting: the pendulum is not near upright, or the device has a latched fault
    armed      |θ| < arm_theta, no fault: the controller was reset (Controller.reset(φ)) and the
               observer tracks for ``settle_ticks`` ticks with u = 0; leaving the window → idle
    balancing  u = L·x + F̂ is sent; trips on |θ| > theta_limit, |φ| > phi_limit, a device fault,
               a non-finite value, ``max_consecutive_overruns`` commanded ticks in a row that each
               missed their deadline
    tripped    latched; u = 0; the run stops

With a swing-up (``SupervisorLimits.swing_up``):

    calibrating  u = 0 while the loop takes the start-up calibration (furuta_rt.runtime.calibration) from
                 the pendulum hanging still; ``calibrated`` → swinging_up, a refusal trips (``calibration``)
    swinging_up  the controller's energy pump drives the actuator; trips as balancing except on |θ|
    balancing    entered and left by the controller's catch / fall (``follow``); the |θ| trip only when
                 the rig's swing_up.on_fall is "trip"

For a hanging experiment (``SupervisorLimits.hanging``: an open-loop plan, furuta_rt.experiment.hanging):

    idle         waiting: the pendulum is not within arm_theta of hanging (θ = π), or a latched fault
    armed        |θ − π| < arm_theta, no fault: reset, u = 0 for ``settle_ticks``; leaving the window → idle
    open_loop    the plan's torque drives the actuator (no feedback); trips on |θ − π| > swing_limit,
                 |φ| > phi_limit, a device fault, a non-finite value, repeated overruns, as balancing

Link loss (no SAMPLE for more than ``link_loss_periods`` periods) and operator stops (SIGINT,
SIGTERM) trip from any state via ``trip``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum

from firmware_protocol import FAULT_MASK, StatusFlags
from furuta_rt.config import SafetyConfig, SwingUpConfig
from furuta_rt.runtime.records import STATE_NAMES


class State(IntEnum):
    IDLE = 0
    ARMED = 1
    BALANCING = 2
    TRIPPED = 3
    CALIBRATING = 4
    SWINGING_UP = 5
    OPEN_LOOP = 6

    @property
    def label(self) -> str:
        return self.name.lower()


assert tuple(s.label for s in State) == STATE_NAMES

_FAULT_MASK = int(FAULT_MASK)
_OVERRANGE_FAULTS = int(StatusFlags.ADC_OVERRANGE | StatusFlags.ENCODER_ERROR)


class TripReason:
    """Stable identifiers of the trip causes (the event text adds the numbers)."""

    THETA_LIMIT = "theta_limit"
    PHI_LIMIT = "phi_limit"
    LINK_LOSS = "link_loss"
    SEQUENCE = "sequence"  # the SAMPLE seq went back: the device restarted without a handshake
    SENSOR_FAULT = "sensor_fault"
    DEVICE_FAULT = "device_fault"
    NONFINITE = "nonfinite"
    OVERRUNS = "overruns"
    OPERATOR_STOP = "operator_stop"
    ERROR = "error"
    CALIBRATION = "calibration"  # the start-up calibration was refused (not hanging still)


@dataclass(frozen=True, slots=True)
class Transition:
    """A state change, for the events channel and the console."""

    seq: int
    old: State
    new: State
    reason: str
    message: str


@dataclass(frozen=True, slots=True)
class SupervisorLimits:
    theta_limit: float = 0.5
    phi_limit: float = 6.0 * math.pi
    arm_theta: float = 0.1
    max_consecutive_overruns: int = 5
    settle_ticks: int = 5
    swing_up: bool = False  # calibrate, then swing up from hanging (rig swing_up.enabled)
    trip_on_fall: bool = True  # with a swing-up: a fall trips (on_fall = "trip") instead of swinging up again
    hanging: bool = False  # a hanging experiment: arm about θ = π, then open loop (no balancing)
    swing_limit: float = 1.0  # with ``hanging``: the |θ − π| beyond which the open-loop experiment trips

    @classmethod
    def from_config(cls, cfg: SafetyConfig, rate_hz: float, swing_up: SwingUpConfig | None = None,
                    hanging_swing: float | None = None) -> SupervisorLimits:
        """Limits from the rig's [safety] (and [swing_up]); the armed window lasts ~10 ms. ``hanging_swing``: a
        hanging experiment, tripping beyond this |θ − π|."""
        return cls(
            theta_limit=cfg.theta_limit,
            phi_limit=cfg.phi_limit,
            arm_theta=cfg.arm_theta,
            max_consecutive_overruns=cfg.max_consecutive_overruns,
            settle_ticks=max(1, round(0.01 * rate_hz)),
            swing_up=swing_up is not None and swing_up.enabled,
            trip_on_fall=swing_up is None or not swing_up.enabled or swing_up.on_fall == "trip",
            hanging=hanging_swing is not None,
            swing_limit=1.0 if hanging_swing is None else hanging_swing,
        )


def from_hanging(theta: float) -> float:
    """|θ − π| wrapped to [0, π]: how far the pendulum is from hanging (θ read modulo 2π or counting turns)."""
    return abs(math.remainder(theta - math.pi, 2.0 * math.pi))


class Supervisor:
    """Decides per tick in which state the controller runs. Latches the first trip."""

    __slots__ = ("_late_run", "_settle", "limits", "reason", "state", "transitions")

    def __init__(self, limits: SupervisorLimits) -> None:
        self.limits = limits
        self.state = State.IDLE
        self.reason = ""
        self._settle = 0
        self._late_run = 0
        self.transitions: list[Transition] = []

    @property
    def tripped(self) -> bool:
        return self.state is State.TRIPPED

    def _go(self, seq: int, new: State, reason: str, message: str) -> State:
        self.transitions.append(Transition(seq, self.state, new, reason, message))
        self.state = new
        return new

    def trip(self, seq: int, reason: str, message: str) -> bool:
        """Trip now (link loss, operator stop, error). Returns False if already tripped."""
        if self.state is State.TRIPPED:
            return False
        self.reason = reason
        self._go(seq, State.TRIPPED, reason, message)
        return True

    def why_not_armed(self, theta: float, phi: float, status: int) -> str:
        """What keeps an idle supervisor from arming at this measurement (for the operator)."""
        lim = self.limits
        why = []
        if lim.hanging and not from_hanging(theta) < lim.arm_theta:
            why.append(f"|θ − π| = {from_hanging(theta):.3f} rad, arms below {lim.arm_theta:g} rad: let the pendulum "
                       "hang still")
        elif not lim.hanging and not abs(theta) < lim.arm_theta:
            why.append(f"|θ| = {abs(theta):.3f} rad, arms below {lim.arm_theta:g} rad: bring the pendulum upright")
        if not abs(phi) < lim.phi_limit:
            why.append(f"|φ| = {abs(phi):.3f} rad beyond {lim.phi_limit:g} rad: turn the arm back")
        if status & _FAULT_MASK:
            why.append(f"device fault {StatusFlags(status & _FAULT_MASK).name} latched (cleared when its cause is gone)")
        return "; ".join(why) or "nothing (it arms at the next sample)"

    def step(self, seq: int, theta: float, phi: float, status: int, late: bool | None) -> tuple[State, bool]:
        """One tick: (state to run this tick in, whether to reset the controller first).

        ``status`` is the SAMPLE's device flags. ``late``: this tick is an overrun (True) or on time
        (False); None for a stale tick that gets no command (it neither counts nor breaks a run of
        overruns: one host stall is one overrun however many periods it skipped).
        """
        s = self.state
        if s is State.TRIPPED:
            return s, False
        lim = self.limits
        if not (math.isfinite(theta) and math.isfinite(phi)):
            self.trip(seq, TripReason.NONFINITE, f"non-finite measurement θ={theta} φ={phi}")
            return State.TRIPPED, False
        if s is State.IDLE and lim.swing_up:
            if status & _FAULT_MASK == 0 and abs(phi) < lim.phi_limit:
                self._late_run = 0
                self._go(seq, State.CALIBRATING, "calibrate", "calibrating: the pendulum must hang still")
                return State.CALIBRATING, False
            return s, False
        off = from_hanging(theta) if lim.hanging else abs(theta)  # from where the run starts: upright or hanging
        if s is State.IDLE:
            if status & _FAULT_MASK == 0 and off < lim.arm_theta and abs(phi) < lim.phi_limit:
                self._settle = 0
                self._late_run = 0
                what = "|θ − π|" if lim.hanging else "|θ|"
                self._go(seq, State.ARMED, "arm", f"armed: {what} = {off:.3f} rad < {lim.arm_theta:g} rad")
                return State.ARMED, True
            return s, False
        # armed, calibrating, swinging up or balancing: the actuator is (about to be) ours, so every fault trips
        if abs(phi) > lim.phi_limit:
            self.trip(seq, TripReason.PHI_LIMIT, f"|φ| = {abs(phi):.3f} rad beyond the cable limit {lim.phi_limit:g} rad")
            return State.TRIPPED, False
        if status & _FAULT_MASK:
            flags = StatusFlags(status & _FAULT_MASK)
            reason = TripReason.SENSOR_FAULT if status & _OVERRANGE_FAULTS else TripReason.DEVICE_FAULT
            self.trip(seq, reason, f"device reports {flags.name} (status {status:#06x})")
            return State.TRIPPED, False
        if s is State.CALIBRATING:
            return s, False
        if s is State.ARMED:
            if off >= lim.arm_theta:
                what = "|θ − π|" if lim.hanging else "|θ|"
                self._go(seq, State.IDLE, "disarm", f"disarmed: {what} = {off:.3f} rad left the arming window")
                return State.IDLE, False
            self._settle += 1
            if self._settle >= lim.settle_ticks:
                if lim.hanging:
                    self._go(seq, State.OPEN_LOOP, "open_loop", "open loop: the experiment's torque drives the arm")
                    return State.OPEN_LOOP, False
                self._go(seq, State.BALANCING, "balance", "balancing")
                return State.BALANCING, False
            return s, False
        if s is State.OPEN_LOOP and off > lim.swing_limit:
            self.trip(seq, TripReason.THETA_LIMIT, f"|θ − π| = {off:.3f} rad beyond the hanging experiment's limit "
                      f"{lim.swing_limit:g} rad")
            return State.TRIPPED, False
        # balancing, swinging up or open loop
        if abs(theta) > lim.theta_limit and s is State.BALANCING and lim.trip_on_fall:
            self.trip(seq, TripReason.THETA_LIMIT, f"|θ| = {abs(theta):.3f} rad beyond the limit {lim.theta_limit:g} rad")
            return State.TRIPPED, False
        if late:
            self._late_run += 1
            if self._late_run >= lim.max_consecutive_overruns:
                self.trip(seq, TripReason.OVERRUNS, f"{self._late_run} consecutive ticks missed their deadline")
                return State.TRIPPED, False
        elif late is not None:
            self._late_run = 0
        return s, False

    def calibrated(self, seq: int, message: str) -> tuple[State, bool]:
        """The start-up calibration is taken: swing up (the controller is reset first)."""
        if self.state is not State.CALIBRATING:
            return self.state, False
        self._go(seq, State.SWINGING_UP, "swing_up", message)
        return State.SWINGING_UP, True

    def follow(self, seq: int, swinging: bool, theta: float) -> State:
        """The controller's catch (swinging_up → balancing) or fall (balancing → swinging_up) after its update."""
        s = self.state
        if s is State.SWINGING_UP and not swinging:
            self._go(seq, State.BALANCING, "catch", f"caught at |θ| = {abs(theta):.3f} rad: balancing")
        elif s is State.BALANCING and swinging:
            self._go(seq, State.SWINGING_UP, "fall", f"fell: |θ| = {abs(theta):.3f} rad, swinging up again")
        return self.state

    def command_not_finite(self, seq: int, u: float) -> None:
        """The controller produced a non-finite command: trip (the loop sends u = 0 instead)."""
        self.trip(seq, TripReason.NONFINITE, f"controller output u = {u} is not finite")
