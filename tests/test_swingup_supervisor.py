"""The swing-up's supervisor states (idle → calibrating → swinging_up → balancing ⇄ swinging_up → tripped) and the
start-up calibration (θ zero from hanging at rest, arm zero), without I/O."""

from __future__ import annotations

import math

import numpy as np
import pytest

from firmware_protocol import StatusFlags
from furuta_rt.config import SafetyConfig, SwingUpConfig, load_rig
from furuta_rt.runtime.calibration import CalibrationWindow, StartupCalibration
from furuta_rt.runtime.records import STATE_NAMES
from furuta_rt.runtime.supervisor import State, Supervisor, SupervisorLimits, TripReason

WATCHDOG = int(StatusFlags.WATCHDOG_TRIPPED)


def swing_supervisor(on_fall: str = "swing_up") -> Supervisor:
    cfg = SwingUpConfig(enabled=True, on_fall=on_fall)  # type: ignore[arg-type]
    return Supervisor(SupervisorLimits.from_config(SafetyConfig(phi_limit=3.0), 500.0, cfg))


def test_states_idle_calibrating_swinging_balancing_and_back() -> None:
    sup = swing_supervisor()
    assert sup.step(0, math.pi, 0.0, 0, False) == (State.CALIBRATING, False)  # hanging: no arming window needed
    assert sup.step(1, math.pi, 0.0, 0, False) == (State.CALIBRATING, False)
    assert sup.calibrated(2, "calibrated") == (State.SWINGING_UP, True)  # the controller is reset for the swing-up
    assert sup.step(3, 2.0, 0.5, 0, False) == (State.SWINGING_UP, False)  # |θ| far beyond theta_limit: no trip
    assert sup.follow(3, False, 0.2) is State.BALANCING
    assert sup.step(4, 0.7, 0.5, 0, False) == (State.BALANCING, False)  # a fall is the controller's, not a trip
    assert sup.follow(4, True, 0.7) is State.SWINGING_UP
    assert [t.new.label for t in sup.transitions] == ["calibrating", "swinging_up", "balancing", "swinging_up"]
    assert [t.reason for t in sup.transitions] == ["calibrate", "swing_up", "catch", "fall"]
    assert sup.step(5, 2.0, 3.5, 0, False) == (State.TRIPPED, False)  # the cable limit trips while swinging
    assert sup.reason == TripReason.PHI_LIMIT


def test_on_fall_trip_trips_on_theta_while_balancing() -> None:
    sup = swing_supervisor("trip")
    sup.step(0, math.pi, 0.0, 0, False)
    sup.calibrated(1, "calibrated")
    assert sup.step(2, 2.5, 0.0, 0, False)[0] is State.SWINGING_UP
    sup.follow(2, False, 0.1)
    assert sup.step(3, 0.6, 0.0, 0, False) == (State.TRIPPED, False)
    assert sup.reason == TripReason.THETA_LIMIT


def test_a_device_fault_while_calibrating_or_swinging_trips() -> None:
    sup = swing_supervisor()
    sup.step(0, math.pi, 0.0, 0, False)
    assert sup.step(1, math.pi, 0.0, WATCHDOG, False)[0] is State.TRIPPED
    sup = swing_supervisor()
    sup.step(0, math.pi, 0.0, 0, False)
    sup.calibrated(1, "ok")
    assert sup.step(2, 1.0, 0.0, WATCHDOG, False)[0] is State.TRIPPED
    assert sup.reason == TripReason.DEVICE_FAULT


def test_without_a_swing_up_the_supervisor_is_unchanged() -> None:
    lim = SupervisorLimits.from_config(SafetyConfig(), 500.0, load_rig("thesis").swing_up)
    assert not lim.swing_up and lim.trip_on_fall
    sup = Supervisor(lim)
    assert sup.step(0, math.pi, 0.0, 0, False) == (State.IDLE, False)
    assert sup.step(1, 0.05, 0.0, 0, False) == (State.ARMED, True)


def test_state_names_cover_the_new_states() -> None:
    assert STATE_NAMES[State.CALIBRATING] == "calibrating" and STATE_NAMES[State.SWINGING_UP] == "swinging_up"


def window_over(theta: np.ndarray, phi: np.ndarray, **cfg: float) -> StartupCalibration | str:
    w = CalibrationWindow(SwingUpConfig(**cfg), 500.0)  # type: ignore[arg-type]
    done = False
    for th, ph in zip(theta.tolist(), phi.tolist(), strict=True):
        done = w.add(th, ph)
    assert done
    return w.result()


def test_calibration_from_hanging_at_rest_across_the_wrap() -> None:
    """A θ sensor with a +0.003 rad zero error reads hanging at −π + 0.003, its noise flipping it across ±π: the zero
    comes out as +0.003 (the mean taken around the first sample), the arm's zero as its mean."""
    rng = np.random.default_rng(3)
    true = math.pi + 0.003 + 2e-3 * rng.standard_normal(500)
    raw = (true + math.pi) % (2 * math.pi) - math.pi
    assert raw.min() < -3.0 and raw.max() > 3.0  # it does wrap
    phi = 0.7 + 1e-3 * rng.standard_normal(500)
    cal = window_over(raw, phi)
    assert isinstance(cal, StartupCalibration)
    assert cal.theta_zero == pytest.approx(0.003, abs=3e-4)  # a plain mean would give ~0
    assert cal.phi_zero == pytest.approx(0.7, abs=3e-4)
    th, ph = cal.apply(0.003, 0.7)  # the sensor's reading of upright
    assert th == pytest.approx(0.0, abs=3e-4) and ph == pytest.approx(0.0, abs=3e-4)
    assert StartupCalibration.from_metadata(cal.metadata()) == cal  # round trip through the log's metadata


def test_calibration_refuses_a_swinging_pendulum_and_one_not_hanging() -> None:
    t = np.arange(500) / 500.0
    swinging = math.pi - 0.05 * np.cos(2 * math.pi * t / 1.12)  # a 0.05 rad swing, the thesis' 1.12 s period
    got = window_over((swinging + math.pi) % (2 * math.pi) - math.pi, np.zeros(500))
    assert isinstance(got, str) and "not hanging still" in got and "θ moved 0.100 rad" in got
    got = window_over(np.full(500, 1.0), np.zeros(500))  # still, but at 1 rad: not hanging
    assert isinstance(got, str) and "from hanging" in got
    got = window_over(np.full(500, math.pi), np.linspace(0.0, 0.2, 500))  # the arm turning
    assert isinstance(got, str) and "φ 0.200 rad" in got


def test_the_loop_calibrates_swings_up_catches_and_shows_it() -> None:
    """The control loop (faster than real time, against the simulator behind the HardwareInterface) with a swing-up:
    idle → calibrating (1 s) → swinging_up → balancing; the calibration goes to the log sink as metadata before
    the swing-up starts; the logged θ is the device's reading; the dashboard shows the state and its hint."""
    from rich.console import Console
    from test_run_loop import RATE, SimDevice

    from furuta_rt.controller.controller import Controller
    from furuta_rt.model.rig import RigModel
    from furuta_rt.runtime.dashboard import render
    from furuta_rt.runtime.loop import ControlLoop, LoopSettings
    from furuta_rt.runtime.records import TICK_RECORD

    rig = load_rig("thesis")
    rig = rig.model_copy(update={"swing_up": rig.swing_up.model_copy(update={"enabled": True})})
    dev = SimDevice(rig, x0=(math.pi, 0.0, 0.0, 0.0))
    items: list[tuple] = []
    snaps: list[dict] = []

    class Sink:
        def __init__(self, into: list) -> None:
            self.into = into

        def put_nowait(self, item: object) -> None:
            self.into.append(item)

    loop = ControlLoop(
        dev, Controller.from_rig(rig), Supervisor(SupervisorLimits.from_config(rig.safety, RATE, rig.swing_up)),
        LoopSettings(rate_hz=RATE, duration=7.0, link_timeout_s=0.004), full_scale=rig.actuator.limit,
        calibration=RigModel.from_config(rig).calibration, log=Sink(items), dashboard=Sink(snaps),
        swing_up=rig.swing_up,
    )
    r = loop.run()
    assert r.end == "duration" and r.catches == 1 and r.falls == 0
    assert r.first_catch_s == pytest.approx(4.37, abs=0.3)  # the simulation of test_swingup (4.37 s frictionless)
    kinds = [it[0] for it in items]
    meta = kinds.index("metadata")
    assert items[meta][1] == "calibration" and abs(float(items[meta][2]["theta_zero"])) < 1e-3
    ticks = [rec for it in items if it[0] == "ticks" for rec in it[1]]
    state = [STATE_NAMES[rec[TICK_RECORD.index("state")]] for rec in ticks]
    # one second of samples: the 500th completes the calibration and its tick already swings up
    assert state[0] == "calibrating" and state.count("calibrating") == RATE - 1
    first_swing = state.index("swinging_up")
    assert all(s == "balancing" for s in state[state.index("balancing"):])
    assert sum(len(it[1]) for it in items[:meta] if it[0] == "ticks") <= first_swing  # calibration logged first
    theta = np.array([rec[TICK_RECORD.index("theta")] for rec in ticks])
    assert np.all(np.abs(np.abs(theta[:RATE]) - math.pi) < 0.01)  # the device's reading: hanging near ±π
    swinging = next(s for s in snaps if s["state"] == "swinging_up")
    console = Console(record=True, width=140)
    console.print(render(swinging))
    console.print(render(snaps[-1]))
    text = console.export_text()
    assert "SWINGING_UP" in text and "swinging up: energy control" in text and "BALANCING" in text, text
