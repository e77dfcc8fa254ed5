"""HIL: `furuta-rt run --mock --swing-up` as a user starts it, the real daemon against hil_mock over a real pty.

The mock starts with the pendulum hanging at rest (`--start hanging`); the daemon calibrates (≈1 s hanging still),
swings up, catches and balances. Per rig the bound on the time from the start of the swing-up to the first catch
is derived from the simulation of the same controller (furuta_rt.sim.swingup_run, computed here):
bound = 1.3 × simulated + 0.5 s (the real-time run has other noise draws, a 16-bit command and tick jitter, which
may cost part of one more pump). At the shipped defaults the simulation gives 5.48 s for the thesis rig with arm
Coulomb friction 0.3 N m (bound 7.6 s), 2.06 s for the QUBE-Servo 2 (3.2 s) and 1.24 s for macstepien (2.1 s).

Checked on the log (θ, φ as the device read them; u as sent) and the summary: the states in order, the first catch
within the bound, |φ| inside the rig's cable limit throughout, |u| within the actuator limit, still balancing at
the end, the calibration in the log's metadata (the thesis run's mock has a θ sensor zero error of 0.04 rad, which
the calibration must find), and replay reproducing every u bit for bit with that calibration applied. The
macstepien run is pushed (`--mock-fault push@T`, a θ̇ jump of 2√(ε/α)) once balancing: the fall is caught by a
new swing-up within the bound the simulation of the same push gives (0.39 s simulated; bound 1.3 × + 0.5 s). The mock runs in
lockstep (each device tick as soon as the COMMAND answering the last SAMPLE arrived): every bound is in device time.
"""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import numpy as np
import pytest
from test_reliability_harness import LOCKSTEP, DaemonProcess, read_summary, traceback_free

from firmware_protocol import StatusFlags
from furuta_rt.config import load_rig
from furuta_rt.io.mcap_read import read_log
from furuta_rt.model.effects import effects_from_assignments
from furuta_rt.replay.core import replay_log
from furuta_rt.runtime.calibration import CALIBRATION_METADATA
from furuta_rt.sim.swingup_run import simulate_swing_up

pytestmark = pytest.mark.hil

THETA_OFFSET = 0.04  # rad: the thesis mock's θ sensor zero error, for the calibration to find
CASES = {  # rig → (mock effects, balanced seconds after the catch, push after the catch (s) or None)
    "thesis": (["arm_coulomb.Fc=0.3", f"theta_offset.offset={THETA_OFFSET}"], 1.5, None),
    "qube_servo2": ([], 1.5, None),
    "macstepien": ([], 1.5, 1.0),
}


def bound(simulated: float) -> float:
    return 1.3 * simulated + 0.5


@pytest.mark.parametrize("name", list(CASES))
def test_swing_up_from_hanging_catches_and_balances(name: str, tmp_path: Path) -> None:
    effects, hold_s, push_after = CASES[name]
    rig = load_rig(name)
    friction = effects_from_assignments([e for e in effects if not e.startswith("theta_offset")]) if effects else None
    sim = simulate_swing_up(rig, 8.0, effects=friction, seed=1)
    limit_s = bound(sim.first_catch_s)
    calibration_s = rig.swing_up.calibration_s
    push_at = None if push_after is None else calibration_s + limit_s + push_after  # plant s since the handshake
    recatch_limit = None
    if push_at is not None:
        pushed = simulate_swing_up(rig, 8.0, effects=friction, seed=1, push_at=sim.first_catch_s + push_after)
        recatch_limit = bound(pushed.recatch_s)
    duration = calibration_s + limit_s + hold_s + (0.0 if push_at is None else push_after + recatch_limit + hold_s)
    # lockstep: every bound here is in device time, so the device need not wait for the wall clock
    args = ["--mock", "--swing-up", "--config", name, "--duration", f"{duration:.2f}", "--no-tui",
            "--log", str(tmp_path / "run.mcap"), "--summary-json", str(tmp_path / "summary.json"),
            LOCKSTEP]
    for e in effects:
        args += ["--mock-effect", e]
    if push_at is not None:
        args += ["--mock-fault", f"push@{push_at:.2f}"]
    d = DaemonProcess(args)
    rc = d.wait(timeout=120)
    out = d.stdout + "\n".join(d.lines)
    assert traceback_free(out), out
    assert rc == 0, out
    s = read_summary(tmp_path)
    assert s["end"] == "duration" and s["final_state"] == "balancing", s["trip_message"]

    log = read_log(tmp_path / "run.mcap")
    tk = log.ticks
    state = tk["state"]
    changes = [state[0]] + [b for a, b in itertools.pairwise(state) if a != b]
    assert changes[:4] == ["idle", "calibrating", "swinging_up", "balancing"] or \
        changes[:3] == ["calibrating", "swinging_up", "balancing"], changes
    t = tk["t"]
    swing_start = t[np.flatnonzero(state == "swinging_up")[0]]
    first_catch = t[np.flatnonzero(state == "balancing")[0]] - swing_start
    assert first_catch <= limit_s, f"caught after {first_catch:.2f} s, simulated {sim.first_catch_s:.2f} s"
    assert s["swing_up"]["first_catch_s"] == pytest.approx(first_catch, abs=0.01)
    cal = log.metadata[CALIBRATION_METADATA]
    phi_zero = float(cal["phi_zero"])
    assert np.max(np.abs(tk["phi"] - phi_zero)) < rig.safety.phi_limit
    assert np.max(np.abs(tk["u"])) <= rig.actuator.limit
    assert np.any(np.abs(tk["u"]) > 0.5 * rig.actuator.limit)  # the swing-up did use the actuator
    expected_zero = THETA_OFFSET if name == "thesis" else 0.0
    assert float(cal["theta_zero"]) == pytest.approx(expected_zero, abs=2e-3)
    end = t >= t[-1] - 0.5
    theta_cal = (tk["theta"] - float(cal["theta_zero"]) + math.pi) % (2 * math.pi) - math.pi
    assert np.all(state[end] == "balancing") and np.max(np.abs(theta_cal[end])) < 0.1
    rep = replay_log(log)
    assert rep.same_config and rep.exact, rep.verdict()
    if push_at is not None:
        fell = np.flatnonzero((state[1:] == "swinging_up") & (state[:-1] == "balancing"))
        assert fell.size >= 1, "the push did not knock the pendulum over"
        fall_t = t[fell[0] + 1]
        assert push_at <= fall_t - t[0] + 0.05  # it fell after the push, not before
        recaught = np.flatnonzero((t > fall_t) & (state == "balancing"))
        assert recaught.size, "not caught again after the push"
        push_t = t[0] + push_at
        assert t[recaught[0]] - push_t <= recatch_limit, (t[recaught[0]] - push_t, recatch_limit)
        assert s["swing_up"]["falls"] >= 1 and s["swing_up"]["catches"] >= 2


def test_calibration_refuses_a_pendulum_that_is_not_hanging_still(tmp_path: Path) -> None:
    """The mock releases the pendulum 0.24 rad from hanging: it swings, the calibration refuses with one line saying
    what moved, the run trips (exit 1) and the actuator was never driven (every logged u is 0, ENABLE never set)."""
    args = ["--mock", "--swing-up", "--mock-initial-theta", "2.9", "--duration", "3", "--no-tui",
            "--log", str(tmp_path / "run.mcap"), "--summary-json", str(tmp_path / "summary.json")]
    d = DaemonProcess(args)
    rc = d.wait(timeout=120)
    err = "\n".join(d.lines)
    assert traceback_free(err + d.stdout), err
    assert rc == 1, err
    s = read_summary(tmp_path)
    assert s["trip_reason"] == "calibration" and "not hanging still" in s["trip_message"]
    assert sum("calibration refused" in line for line in d.lines) == 1, err
    log = read_log(tmp_path / "run.mcap")
    assert np.all(log.ticks["u"] == 0.0)
    assert not np.any(log.ticks["status"] & int(StatusFlags.ENABLED))  # the device never drove the arm
    assert CALIBRATION_METADATA not in log.metadata


def test_swing_up_on_a_rig_whose_theta_stops_at_pi_is_refused(tmp_path: Path) -> None:
    """A ±π θ sensor (sensors.theta_wraps = false) cannot see the pendulum hang: one line naming the key, exit 2."""
    rig = tmp_path / "rig.toml"
    text = (Path(__file__).parents[1] / "furuta_rt" / "rigs" / "thesis.toml").read_text()
    rig.write_text(text.replace("theta_wraps = true", "theta_wraps = false", 1))
    d = DaemonProcess(["--mock", "--swing-up", "--config", str(rig), "--duration", "1", "--no-tui"])
    rc = d.wait(timeout=60)
    assert rc == 2
    lines = [line for line in d.lines if line.strip()]
    assert len(lines) == 1 and "sensors.theta_wraps" in lines[0] and "Traceback" not in lines[0], lines
