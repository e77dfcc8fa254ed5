"""Designed experiments, the run: the plan format, its tick-by-tick excitation through the one ``Controller.update``,
and `furuta-rt run --experiment` against hil_mock over a real pty (segments as events in the MCAP, read back with
the official ``mcap`` reader; a fault during an experiment trips and zeroes first at the device), balancing and
hanging (open loop about θ = π: the supervisor's open_loop state)."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest
from test_reliability_harness import (
    LOCKSTEP,
    DaemonProcess,
    MockProcess,
    MockRecord,
    read_summary,
    start_daemon,
    traceback_free,
    write_test_rig,
)

from firmware_protocol import COMMAND_FULL_SCALE, CommandFlags, StatusFlags
from furuta_rt.config import load_rig
from furuta_rt.controller.controller import Controller, Measurement
from furuta_rt.errors import UserError
from furuta_rt.experiment import hanging
from furuta_rt.experiment.plan import (
    EVENT_PREFIX,
    Excitation,
    Plan,
    Segment,
    check_plan_limits,
    load_plan,
    plan_from_dict,
    plan_of_log,
    reference_and_torque,
    segments_in_log,
)
from furuta_rt.io import log_schema as ls
from furuta_rt.io.mcap_read import read_log
from furuta_rt.replay.core import replay_log
from furuta_rt.runtime.supervisor import State, Supervisor, SupervisorLimits
from furuta_rt.sim.closed_loop import run_closed_loop

RATE = 500
PLAN = """
settle_s = 1.0
return_speed = 0.5

[[segment]]
kind = "step"
phi = 0.3
duration = 1.5

[[segment]]
kind = "sweep"
amplitude = 0.4
speed = 0.8
duration = 2.0
dither = 0.05
dither_hz = 15.0

[[segment]]
kind = "chirp"
amplitude = 0.05
f0 = 0.5
f1 = 4.0
duration = 2.0
"""


def write_plan(tmp: Path, text: str = PLAN) -> Path:
    path = tmp / "plan.toml"
    path.write_text(text)
    return path


# ------------------------------------------------------------------ the plan and its excitation
def test_plan_signals_follow_their_definitions() -> None:
    """Step holds its target, a sweep moves at ±speed inside ±amplitude, a chirp sweeps its band, the reference
    returns to 0 at return_speed; the round trip through TOML keeps the plan."""
    import tomllib

    plan = plan_from_dict(tomllib.loads(PLAN))
    assert plan_from_dict(tomllib.loads(plan.to_toml())) == plan
    ref, dot, u = reference_and_torque(plan, RATE)
    step, sweep, chirp = (slice(0, 750), slice(750, 1750), slice(1750, 2750))
    assert np.all(ref[step] == 0.3) and np.all(u[step] == 0.0)
    s_ref, s_dot = ref[sweep], dot[sweep]
    assert np.abs(s_ref).max() <= 0.4 + 1e-12 and set(np.unique(np.abs(s_dot))) == {0.8}
    assert np.allclose(np.diff(s_ref) * RATE, s_dot[:-1], atol=1e-9) or np.sum(  # the velocity is the slope except at
        ~np.isclose(np.diff(s_ref) * RATE, s_dot[:-1])) <= 2  # the turns
    dither = u[sweep]
    assert np.abs(dither).max() == pytest.approx(0.05, rel=1e-3)
    # the chirp: amplitude 0.05, zero crossings spaced as 1/(2 f) with f rising from 0.5 to 4 Hz
    c = u[chirp]
    assert np.abs(c).max() == pytest.approx(0.05, rel=1e-3)
    assert ref[chirp] == pytest.approx(np.full(1000, 0.3))  # held where the sweep ended (+0.3 rad)
    crossings = (np.flatnonzero(np.diff(np.signbit(c))[1:]) + 1.5) / RATE  # sign changes after t = 0
    phase = 0.5 * crossings + 0.5 * (3.5 / 2.0) * crossings**2  # ∫f dt with f = 0.5 + 1.75 t Hz
    assert np.allclose(phase * 2, np.arange(1, len(crossings) + 1), atol=4.0 / RATE * 2)  # a half cycle each
    assert len(crossings) == math.floor(2 * (0.5 * 2.0 + 0.5 * 1.75 * 4.0) - 1e-9)
    # the return: ramp at 0.5 rad/s to exactly 0
    tail = ref[2750:]
    assert tail[-1] == 0.0 and len(tail) == math.ceil(abs(ref[2749]) / 0.5 * RATE) and np.all(np.diff(tail) < 0)
    assert plan.duration == pytest.approx(len(ref) / RATE, abs=2.0 / RATE)


def test_excitation_settles_marks_segments_and_ends() -> None:
    import tomllib

    plan = plan_from_dict(tomllib.loads(PLAN))
    exc = Excitation(plan, RATE)
    ref, _, _ = reference_and_torque(plan, RATE)
    messages, seen = [], []
    for _ in range(exc.ticks + 3):
        seen.append(exc.step())
        m = exc.take_message()
        if m is not None:
            messages.append(m)
    assert seen[:RATE] == [(0.0, 0.0, 0.0)] * RATE  # settle_s = 1 s of plain balancing
    assert [r for r, _, _ in seen[RATE : RATE + len(ref)]] == ref.tolist()
    assert exc.done and seen[-1] == (0.0, 0.0, 0.0)
    assert [m.split(" start")[0] for m in messages] == [
        f"{EVENT_PREFIX} segment 1/3 step", f"{EVENT_PREFIX} segment 2/3 sweep", f"{EVENT_PREFIX} segment 3/3 chirp",
        f"{EVENT_PREFIX} return", f"{EVENT_PREFIX} end"]


@pytest.mark.parametrize(("text", "needle"), [
    ('[[segment]]\nkind = "wiggle"\nduration = 1', "kind = 'wiggle'"),
    ('[[segment]]\nkind = "step"\nphi = 0.2', "no duration"),
    ('[[segment]]\nkind = "ramp"\nphi = 1.0\nspeed = 0.1\nduration = 2', "takes 10 s"),
    ('[[segment]]\nkind = "chirp"\namplitude = 0.1\nf0 = 3\nf1 = 1\nduration = 2', "must be above f0"),
    ('[[segment]]\nkind = "dither"\namplitude = 0.1\nfrequency = 5\nduration = 2\nphase = 1', "unknown key 'phase'"),
    ('[[segment]]\nkind = "hold"\nduration = 2\ndither = 0.1', "needs dither_hz"),
    ('mode = "swinging"\n[[segment]]\nkind = "hold"\nduration = 1', "mode = 'swinging'; one of balancing, hanging"),
    ('mode = "hanging"\n[[segment]]\nkind = "sweep"\namplitude = 0.3\nspeed = 0.1\nduration = 1',
     "hanging plans take chirp, dither and hold"),
    ("settle_s = 1", "no [[segment]]"),
    ("settle_s = [", "not valid TOML"),
    ("", "no [[segment]]"),
])
def test_bad_plans_are_one_line_errors(tmp_path: Path, text: str, needle: str) -> None:
    with pytest.raises(UserError) as err:
        load_plan(write_plan(tmp_path, text))
    assert needle in str(err.value) and "\n" not in str(err.value)


def test_plan_beyond_the_rig_limits_is_refused() -> None:
    import tomllib

    plan = plan_from_dict(tomllib.loads(PLAN))
    check_plan_limits(plan, u_limit=2.0, phi_limit=1.0)
    with pytest.raises(UserError, match="beyond 80% of the rig's"):
        check_plan_limits(plan, u_limit=2.0, phi_limit=0.45)
    with pytest.raises(UserError, match=r"adds up to 0\.05 to u"):
        check_plan_limits(plan, u_limit=0.06, phi_limit=1.0)


def test_controller_follows_the_arm_reference_in_simulation() -> None:
    """The excitation goes through Controller.update: in the simulator the arm settles at the step's 0.3 rad
    (eq. 5 about φ_r) and the chirp's torque shows in u − u_comp beyond the loop's own."""
    import tomllib

    rig = load_rig("thesis")
    plan = plan_from_dict(tomllib.loads(PLAN))
    exc = Excitation(plan, RATE)
    rec = run_closed_loop(rig, exc.ticks / RATE + 3.0, excitation=exc, mode="none")
    step_end = slice(RATE + 650, RATE + 750)  # the last 0.2 s of the step
    assert np.mean(rec.phi[step_end]) == pytest.approx(0.3, abs=0.03)
    assert np.abs(rec.theta).max() < 0.1 and np.mean(rec.phi[-RATE:]) == pytest.approx(0.0, abs=0.03)  # back at 0
    assert exc.done


# ------------------------------------------------------------------ over the pty
def _official_mcap(path: Path) -> tuple[list[str], dict[str, dict[str, str]]]:
    """Event messages and metadata as the official mcap reader (the ``mcap`` package) reads them."""
    from mcap.reader import make_reader

    with path.open("rb") as f:
        reader = make_reader(f)
        events = [json.loads(m.data)["message"] for _, _, m in reader.iter_messages(topics=[ls.EVENTS_TOPIC])]
    with path.open("rb") as f:
        meta = {m.name: dict(m.metadata) for m in make_reader(f).iter_metadata()}
    return events, meta


@pytest.mark.hil
def test_run_experiment_on_the_mock_logs_its_segments(tmp_path: Path) -> None:
    """`furuta-rt run --mock --experiment plan.toml`: balances, runs the plan, ends with it (exit 0); the MCAP holds
    one event per segment at the ticks the plan puts them, the plan as metadata; the log replays bit for bit."""
    plan_path = write_plan(tmp_path)
    d = DaemonProcess(["--mock", "--experiment", str(plan_path), "--no-tui", "--log", str(tmp_path / "run.mcap"),
                       "--summary-json", str(tmp_path / "summary.json"), LOCKSTEP])
    rc = d.wait(timeout=120)
    assert rc == 0 and traceback_free(d.stderr), d.stderr
    s = read_summary(tmp_path)
    assert s["end"] == "experiment" and "experiment plan completed" in d.stdout
    events, meta = _official_mcap(tmp_path / "run.mcap")
    marks = [e for e in events if e.startswith(EVENT_PREFIX)]
    assert [m.split(":")[1].split(" start")[0].strip() for m in marks] == [
        "segment 1/3 step", "segment 2/3 sweep", "segment 3/3 chirp", "return", "end"], marks
    assert "experiment" in meta and meta["run"]["experiment"] == str(plan_path)
    log = read_log(tmp_path / "run.mcap")
    plan = plan_of_log(log.metadata)
    assert plan == load_plan(plan_path)
    spans = segments_in_log(plan, log.ticks["state"], log.ticks["t"], RATE)
    assert [sp.label for sp in spans] == ["1/3 step", "2/3 sweep", "3/3 chirp", "return"]
    # each event sits at its segment's first tick on the log's time line
    ev_t = {e["message"].split(" start")[0]: e["log_time"] for e in log.events if e["message"].startswith(EVENT_PREFIX)}
    assert len(ev_t) == 5
    step = spans[0]
    t = log.ticks
    assert np.mean(t["phi"][step.stop - 100 : step.stop]) == pytest.approx(0.3, abs=0.05)  # the arm went to 0.3 rad
    assert np.abs(t["theta"][t["state"] == "balancing"]).max() < 0.2
    assert replay_log(log).exact


@pytest.mark.hil
def test_fault_during_an_experiment_trips_and_zeroes_first(tmp_path: Path) -> None:
    """The device goes silent in the middle of the sweep: link loss trips (exit 1), the last COMMAND the device
    acted on is u = 0 (or STOP), and the log ends inside the experiment with its segments so far."""
    plan_path = write_plan(tmp_path)
    mock = MockProcess(tmp_path, ["--fault", "mute@3.5:500ms"])
    d = start_daemon(tmp_path, mock.port, duration=None, extra=["--experiment", str(plan_path),
                                                                   "--link-timeout-ms", "60"])
    rc = d.wait(timeout=120)
    rec = mock.stop()
    assert rc == 1 and traceback_free(d.stderr), d.stderr
    s = read_summary(tmp_path)
    assert s["trip_reason"] == "link_loss", s
    rec.assert_ends_safe()
    msgs = [e["message"] for e in read_log(tmp_path / "run.mcap").events]
    marks = [m for m in msgs if m.startswith(EVENT_PREFIX)]
    assert marks and not any(m == f"{EVENT_PREFIX} end" for m in marks), marks
    assert any("segment 2/3 sweep" in m for m in marks) or any("segment 1/3 step" in m for m in marks)


def test_run_refuses_a_plan_beyond_the_limits_before_starting(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """A dither of 1.9 N m against the thesis rig's 2 N m limit: exit 2, one line, nothing started."""
    from furuta_rt.cli import main

    plan = write_plan(tmp_path, '[[segment]]\nkind = "dither"\namplitude = 1.9\nfrequency = 5\nduration = 2\n')
    rc = main(["run", "--mock", "--experiment", str(plan), "--no-tui", "--log", str(tmp_path / "run.mcap")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "adds up to 1.9 to u" in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "run.mcap").exists()


def test_run_refuses_a_hanging_plan_with_a_swing_up(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """A hanging plan starts from the pendulum hanging at rest, a swing-up leaves it upright: exit 2, one line naming
    why, nothing started."""
    from furuta_rt.cli import main

    plan = write_plan(tmp_path, HANGING_PLAN)
    rc = main(["run", "--mock", "--swing-up", "--experiment", str(plan), "--no-tui", "--log", str(tmp_path / "run.mcap")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "cannot follow a swing-up" in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "run.mcap").exists()


# ------------------------------------------------------------------ hanging: open loop about θ = π
HANGING_PLAN = """
mode = "hanging"
settle_s = 0.5

[[segment]]
kind = "chirp"
amplitude = 0.03
f0 = 0.4
f1 = 1.6
duration = 3.0

[[segment]]
kind = "hold"
duration = 0.5
"""
HANGING_LIMITS = SupervisorLimits(theta_limit=0.5, phi_limit=1.0, arm_theta=0.1, settle_ticks=5, hanging=True,
                                  swing_limit=1.0)


def _steps(sup: Supervisor, thetas: list[float], phi: float = 0.0, status: int = 0) -> list[str]:
    return [sup.step(k, th, phi, status, False)[0].label for k, th in enumerate(thetas)]


def test_hanging_supervisor_arms_about_pi_and_runs_open_loop() -> None:
    """Arms within arm_theta of θ = π read either side of the ±π wrap, opens the loop after settle_ticks, disarms on
    leaving the window; upright does not arm it (and θ = π does not arm a balancing supervisor)."""
    sup = Supervisor(HANGING_LIMITS)
    assert _steps(sup, [0.0, 0.05, 2.9]) == ["idle"] * 3  # upright is not where a hanging experiment starts
    states = _steps(sup, [-3.10, 3.12, -3.13, 3.139, -3.14, 3.141, 3.0])
    assert states == ["armed"] * 5 + ["open_loop", "open_loop"], states
    assert "|θ − π| = 0.042 rad" in sup.transitions[0].message
    sup2 = Supervisor(HANGING_LIMITS)
    assert _steps(sup2, [3.1, 3.1, 2.9]) == ["armed", "armed", "idle"]
    assert _steps(Supervisor(dataclasses.replace(HANGING_LIMITS, hanging=False)), [math.pi, -3.1]) == ["idle", "idle"]
    assert "let the pendulum hang still" in Supervisor(HANGING_LIMITS).why_not_armed(0.3, 0.0, 0)


@pytest.mark.parametrize(("theta", "phi", "status", "reason"), [
    (math.pi - 1.05, 0.0, 0, "theta_limit"),  # swung beyond the hanging limit (1 rad) one way
    (-math.pi + 1.05, 0.0, 0, "theta_limit"),  # ... and the other, across the wrap
    (math.pi, 1.01, 0, "phi_limit"),
    (math.pi, 0.0, int(StatusFlags.WATCHDOG_TRIPPED), "device_fault"),
    (math.pi, 0.0, int(StatusFlags.ENCODER_ERROR), "sensor_fault"),
    (math.nan, 0.0, 0, "nonfinite"),
])
def test_hanging_supervisor_trips_open_loop(theta: float, phi: float, status: int, reason: str) -> None:
    sup = Supervisor(HANGING_LIMITS)
    assert _steps(sup, [math.pi] * 6)[-1] == "open_loop"
    assert _steps(sup, [math.pi - 0.95, -math.pi + 0.95]) == ["open_loop"] * 2  # within 1 rad of hanging: runs on
    state, _ = sup.step(99, theta, phi, status, False)
    assert state is State.TRIPPED and sup.reason == reason, sup.transitions[-1]
    assert sup.step(100, math.pi, 0.0, 0, False)[0] is State.TRIPPED  # latched


def test_open_loop_controller_commands_the_plans_torque_saturated() -> None:
    """A hanging plan through Controller.update: u is the plan's torque tick for tick (zero while settling), no
    feedback (θ and φ do not change it), clipped at the actuator limit and flagged saturated."""
    import tomllib

    rig = load_rig("thesis")
    plan = plan_from_dict(tomllib.loads(HANGING_PLAN))
    ctrl = Controller.from_rig(rig)
    ctrl.excitation = Excitation(plan, RATE)
    rng = np.random.default_rng(1)
    us = [ctrl.update(Measurement(k / RATE, math.pi + 0.1 * rng.standard_normal(), rng.standard_normal(),
                                  0.2 * rng.standard_normal())) for k in range(ctrl.excitation.ticks)]
    _, _, torque = reference_and_torque(plan, RATE)
    assert [o.u for o in us] == [0.0] * 250 + torque.tolist()
    assert not any(o.saturated for o in us) and all(o.u_comp == 0.0 for o in us)
    loud = Plan((Segment("dither", 1.0, {"amplitude": 3.0, "frequency": 2.0}),), "hanging", 0.0)
    ctrl = Controller.from_rig(rig)
    ctrl.excitation = Excitation(loud, RATE)
    out = [ctrl.update(Measurement(k / RATE, math.pi, 0.0, 0.0)) for k in range(RATE)]
    assert max(abs(o.u) for o in out) == rig.actuator.limit and any(o.saturated for o in out)
    assert all(abs(o.u) <= rig.actuator.limit for o in out)


def _device_commands(rec: MockRecord) -> dict[int, tuple[int, int]]:
    """seq → (counts, flags) of the COMMANDs the device accepted (its own record)."""
    return {c[3]: (c[4], c[5]) for c, ok in zip(rec.commands, rec.accepted, strict=True) if ok}


def _counts(u: np.ndarray, full_scale: float) -> np.ndarray:
    return np.clip(np.round(u / full_scale * COMMAND_FULL_SCALE), -COMMAND_FULL_SCALE, COMMAND_FULL_SCALE).astype(int)


@pytest.mark.hil
def test_run_hanging_experiment_over_the_pty(tmp_path: Path) -> None:
    """`furuta-rt run --experiment hanging.toml` against hil_mock started hanging, lockstep-paced: arms about π,
    runs the plan open loop (exit 0, ended by the plan), every segment an event at its tick; the device received
    exactly the plan's torque, tick for tick, with ENABLE, and nothing before arming; the pendulum swung; the log
    replays bit for bit."""
    plan_path = write_plan(tmp_path, HANGING_PLAN)
    mock = MockProcess(tmp_path, ["--start", "hanging", "--pacing", "lockstep"])
    d = start_daemon(tmp_path, mock.port, duration=None, extra=["--experiment", str(plan_path)])
    rc = d.wait(timeout=120)
    rec = mock.stop()
    assert rc == 0 and traceback_free(d.stderr), d.stderr
    s = read_summary(tmp_path)
    assert s["end"] == "experiment" and s["open_loop_ticks"] > 0 and s["balancing_ticks"] == 0, s
    rec.assert_ends_safe()
    log = read_log(tmp_path / "run.mcap")
    plan = plan_of_log(log.metadata)
    assert plan == load_plan(plan_path)
    t = log.ticks
    spans = segments_in_log(plan, t["state"], t["t"], RATE)
    assert [sp.label for sp in spans] == ["1/2 chirp", "2/2 hold"]
    marks = [e["message"] for e in log.events if e["message"].startswith(EVENT_PREFIX)]
    assert [m.split(" start")[0] for m in marks] == [f"{EVENT_PREFIX} segment 1/2 chirp",
                                                      f"{EVENT_PREFIX} segment 2/2 hold", f"{EVENT_PREFIX} end"]
    opened = np.flatnonzero(t["state"] == "open_loop")
    assert len(opened) and set(t["state"][: opened[0]]) <= {"idle", "armed"}
    # the device side: the plan's torque in counts, with ENABLE, answering each open-loop SAMPLE; zero before
    _, _, torque = reference_and_torque(plan, RATE)
    full_scale = float(log.metadata["device"]["actuator_full_scale"])
    got = _device_commands(rec)
    first = int(t["seq"][opened[0]])  # the plan's tick i answers SAMPLE first + i (the device's own numbering)
    want = _counts(np.concatenate([np.zeros(250), torque]), full_scale)
    answered = [i for i in range(len(want)) if first + i in got]  # a SAMPLE the host found stale gets no COMMAND
    assert len(answered) >= 0.99 * len(want)
    assert [got[first + i] for i in answered] == [(int(want[i]), int(CommandFlags.ENABLE)) for i in answered]
    assert all(got[int(q)] == (0, 0) for q in t["seq"][: opened[0]] if int(q) in got)
    assert 0.01 < hanging.swing(t["theta"][opened]) < 1.0 and np.abs(t["phi"]).max() > 0.05
    assert replay_log(log).exact


@pytest.mark.hil
@pytest.mark.parametrize("fault", ["phi_limit", "device_fault"])
def test_fault_during_a_hanging_experiment_zeroes_at_the_device_first(tmp_path: Path, fault: str) -> None:
    """A fault during the open-loop chirp: the arm beyond a |φ| limit of 0.15 rad, or the device's own watchdog
    (host→device bytes lost for 60 ms: the mock's deaf fault, WATCHDOG_TRIPPED in the SAMPLE). The run trips (exit 1,
    that reason); at the device the output is zero from the tripping tick on — the COMMAND answering the SAMPLE
    that tripped is u = 0 without ENABLE, every later one too, then a STOP (on its watchdog the device zeroed itself
    before the SAMPLE that told the host) — and the explanation is logged for that same SAMPLE."""
    plan_path = write_plan(tmp_path, HANGING_PLAN)
    if fault == "phi_limit":
        mock = MockProcess(tmp_path, ["--start", "hanging", "--pacing", "lockstep"])
        rig, watchdog = write_test_rig(tmp_path, phi_limit=0.15), 500
    else:
        mock = MockProcess(tmp_path, ["--start", "hanging", "--pacing", "lockstep", "--fault", "deaf@2.0:60ms"])
        rig, watchdog = write_test_rig(tmp_path), 20
    d = start_daemon(tmp_path, mock.port, duration=None, watchdog_ms=watchdog, rig=rig,
                     extra=["--experiment", str(plan_path)])
    rc = d.wait(timeout=120)
    rec = mock.stop()
    assert rc == 1 and traceback_free(d.stderr), d.stderr
    s = read_summary(tmp_path)
    assert s["trip_reason"] == fault, s
    log = read_log(tmp_path / "run.mcap")
    trip = next(e["message"] for e in log.events if "open_loop → tripped" in e["message"])
    k = int(trip.rsplit("(seq ", 1)[1].rstrip(")"))
    assert int(log.ticks["seq"][-1]) == k  # the tripping tick is the log's last
    got = _device_commands(rec)
    assert all(v == (0, 0) for q, v in got.items() if q >= k), {q: v for q, v in got.items() if q >= k}
    assert any(v[0] != 0 for q, v in got.items() if q < k)  # the plan did drive the arm before
    assert rec.final_output == 0.0
    if fault == "phi_limit":
        assert "|φ| = " in trip and got[k] == (0, 0), (trip, got.get(k))  # the trip tick's own answer: u = 0
        assert rec.stops and rec.stops[-1][0] >= max(c[0] for c in rec.commands)  # then STOP
    else:  # the device zeroed itself on its watchdog before the SAMPLE that told the host (its STOP may be lost: deaf)
        assert "device reports WATCHDOG_TRIPPED" in trip and rec.stats["watchdog_trips"] >= 1, (trip, rec.stats)
        zeroed = next(dev_ns for _, dev_ns, u in reversed(rec.outputs) if u == 0.0)
        assert all(u == 0.0 for _, dev_ns, u in rec.outputs if dev_ns >= zeroed)
        assert zeroed <= round(float(log.ticks["t"][-1]) * 1e9), (zeroed, log.ticks["t"][-1])
    marks = [e["message"] for e in log.events if e["message"].startswith(EVENT_PREFIX)]
    assert marks and f"{EVENT_PREFIX} end" not in marks


@pytest.mark.hil
def test_hanging_design_family_worst_case_stays_within_limits_over_the_pty(tmp_path: Path) -> None:
    """The design's hanging family's largest excitation (a chirp of 3 % of the |u| limit across 0.5–2× the
    natural frequency, here for 20 s: the one driving the arm furthest) run over the pty on the nominal mock:
    no trip, and the device-side peaks — |u| the device received, |φ| and |θ − π| it reported — stay within the
    rig's limits and within 15 % of what hanging.simulate predicts for the plan (the prediction the design's limit
    check uses, so a plan design accepts is one the rig accepts)."""
    rig = load_rig("thesis")
    worst = hanging.candidate_plans(rig, 20.0, settle_s=0.5)[6]
    assert worst.segments[0].kind == "chirp" and worst.segments[0].params["amplitude"] == 0.03 * rig.actuator.limit
    plan_path = tmp_path / "worst.toml"
    plan_path.write_text(worst.to_toml())
    predicted = hanging.simulate(rig, {}, worst, 0, substep_hz=2000.0, noise=False)
    mock = MockProcess(tmp_path, ["--start", "hanging", "--pacing", "lockstep"])
    d = start_daemon(tmp_path, mock.port, duration=None, extra=["--experiment", str(plan_path)])
    rc = d.wait(timeout=300)
    rec = mock.stop()
    assert rc == 0 and traceback_free(d.stderr), d.stderr
    log = read_log(tmp_path / "run.mcap")
    t = log.ticks
    opened = t["state"] == "open_loop"
    full_scale = float(log.metadata["device"]["actuator_full_scale"])
    u_peak = max(abs(c[4]) for c in rec.commands) / COMMAND_FULL_SCALE * full_scale
    phi_peak, swing_peak = float(np.abs(t["phi"][opened]).max()), hanging.swing(t["theta"][opened])
    assert u_peak <= 0.8 * rig.actuator.limit and phi_peak < rig.safety.phi_limit and swing_peak < hanging.SWING_LIMIT
    assert u_peak == pytest.approx(float(np.abs(predicted.u).max()), rel=1e-3)
    assert phi_peak == pytest.approx(float(np.abs(predicted.phi).max()), rel=0.15)
    assert swing_peak == pytest.approx(hanging.swing(predicted.theta), rel=0.15)
