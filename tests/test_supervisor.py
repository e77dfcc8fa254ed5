"""The safety supervisor as a pure state machine: arming only near upright, every trip cause, latching."""

from __future__ import annotations

import math

import pytest

from firmware_protocol import StatusFlags
from furuta_rt.config import load_rig
from furuta_rt.io.log_schema import TICK_FIELDS
from furuta_rt.runtime.supervisor import STATE_NAMES, State, Supervisor, SupervisorLimits, TripReason

LIMITS = SupervisorLimits(theta_limit=0.5, phi_limit=18.85, arm_theta=0.1, max_consecutive_overruns=5, settle_ticks=3)
WATCHDOG = int(StatusFlags.WATCHDOG_TRIPPED)
OVERRANGE = int(StatusFlags.ADC_OVERRANGE)


def balancing() -> Supervisor:
    sup = Supervisor(LIMITS)
    steps = [sup.step(k, 0.02, 0.0, 0, False) for k in range(LIMITS.settle_ticks + 1)]
    assert steps[0] == (State.ARMED, True), "arming resets the controller, once"
    assert [s for s, _ in steps[1:]] == [State.ARMED] * (LIMITS.settle_ticks - 1) + [State.BALANCING]
    assert not any(reset for _, reset in steps[1:])
    return sup


def test_state_names_are_the_logged_enum() -> None:
    assert STATE_NAMES == ("idle", "armed", "balancing", "tripped", "calibrating", "swinging_up", "open_loop")
    assert list(STATE_NAMES) == TICK_FIELDS["state"]["enum"]


def test_limits_from_the_rig_config() -> None:
    rig = load_rig("thesis")
    lim = SupervisorLimits.from_config(rig.safety, 500)
    assert (lim.theta_limit, lim.phi_limit, lim.arm_theta) == (0.5, 18.85, 0.1)
    assert lim.max_consecutive_overruns == rig.safety.max_consecutive_overruns
    assert lim.settle_ticks == 5  # 10 ms at 500 Hz


def test_hanging_pendulum_stays_idle_without_tripping() -> None:
    """Hanging down (θ = π, the θ ADC at its rail) is not a fault while idle: nothing is driven."""
    sup = Supervisor(LIMITS)
    for k in range(100):
        assert sup.step(k, math.pi, 0.3, OVERRANGE, False) == (State.IDLE, False)
    assert sup.transitions == []


@pytest.mark.parametrize(("theta", "phi", "status"), [(0.1, 0.0, 0), (-0.12, 0.0, 0), (0.0, 19.0, 0), (0.0, 0.0, WATCHDOG)])
def test_no_arming_outside_the_window_or_with_a_latched_fault(theta: float, phi: float, status: int) -> None:
    sup = Supervisor(LIMITS)
    assert sup.step(0, theta, phi, status, False) == (State.IDLE, False)


def test_leaving_the_arming_window_disarms() -> None:
    sup = Supervisor(LIMITS)
    assert sup.step(0, 0.05, 0.0, 0, False) == (State.ARMED, True)
    assert sup.step(1, 0.11, 0.0, 0, False) == (State.IDLE, False)
    assert sup.step(2, 0.05, 0.0, 0, False) == (State.ARMED, True), "re-arming resets again"
    assert [t.new for t in sup.transitions] == [State.ARMED, State.IDLE, State.ARMED]


@pytest.mark.parametrize(
    ("theta", "phi", "status", "reason"),
    [
        (0.51, 0.0, 0, TripReason.THETA_LIMIT),
        (-0.6, 0.0, 0, TripReason.THETA_LIMIT),
        (0.0, -18.9, 0, TripReason.PHI_LIMIT),
        (0.0, 0.0, OVERRANGE, TripReason.SENSOR_FAULT),
        (0.0, 0.0, int(StatusFlags.ENCODER_ERROR), TripReason.SENSOR_FAULT),
        (0.0, 0.0, WATCHDOG, TripReason.DEVICE_FAULT),
        (math.nan, 0.0, 0, TripReason.NONFINITE),
        (0.0, math.inf, 0, TripReason.NONFINITE),
    ],
)
def test_balancing_trips_and_latches(theta: float, phi: float, status: int, reason: str) -> None:
    sup = balancing()
    assert sup.step(100, 0.3, 1.0, 0, False) == (State.BALANCING, False), "inside the limits it keeps balancing"
    assert sup.step(101, theta, phi, status, False) == (State.TRIPPED, False)
    assert sup.reason == reason and sup.tripped
    last = sup.transitions[-1]
    assert (last.old, last.new, last.seq, last.reason) == (State.BALANCING, State.TRIPPED, 101, reason)
    # latched: even a perfect sample does not leave tripped, and there is no second transition
    assert sup.step(102, 0.0, 0.0, 0, False) == (State.TRIPPED, False)
    assert [t.new for t in sup.transitions] == [State.ARMED, State.BALANCING, State.TRIPPED]


def test_theta_limit_is_a_balancing_limit_and_armed_trips_on_faults() -> None:
    sup = Supervisor(LIMITS)
    sup.step(0, 0.05, 0.0, 0, False)
    assert sup.step(1, 0.05, 0.0, WATCHDOG, False) == (State.TRIPPED, False)
    assert sup.reason == TripReason.DEVICE_FAULT


def test_consecutive_overruns_trip_but_one_stall_does_not() -> None:
    sup = balancing()
    n = LIMITS.max_consecutive_overruns
    for k in range(n - 1):  # n-1 late ticks, then one on time: the count restarts
        assert sup.step(10 + k, 0.0, 0.0, 0, True)[0] is State.BALANCING
    assert sup.step(20, 0.0, 0.0, 0, False)[0] is State.BALANCING
    # stale ticks (late=None: skipped periods of one stall) neither count nor reset
    for k in range(n - 1):
        assert sup.step(30 + 2 * k, 0.0, 0.0, 0, True)[0] is State.BALANCING
        assert sup.step(31 + 2 * k, 0.0, 0.0, 0, None)[0] is State.BALANCING
    assert sup.step(50, 0.0, 0.0, 0, True) == (State.TRIPPED, False)
    assert sup.reason == TripReason.OVERRUNS and str(n) in sup.transitions[-1].message


def test_external_trips_from_any_state_keep_the_first_reason() -> None:
    sup = Supervisor(LIMITS)
    assert sup.trip(7, TripReason.LINK_LOSS, "link loss: no SAMPLE for 5.0 ms")
    assert sup.state is State.TRIPPED and sup.reason == TripReason.LINK_LOSS
    assert not sup.trip(8, TripReason.OPERATOR_STOP, "operator stop (SIGINT)")
    assert sup.reason == TripReason.LINK_LOSS and len(sup.transitions) == 1
    sup2 = balancing()
    sup2.command_not_finite(5, math.nan)
    assert sup2.reason == TripReason.NONFINITE and "not finite" in sup2.transitions[-1].message
