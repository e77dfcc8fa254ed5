"""Designed experiments, the run: the plan format, its tick-by-tick excitation through the one ``Controller.update``,
and `furuta-rt run --experiment` against hil_mock over a real pty (segments as events in the MCAP, read back with
the official ``mcap`` reader; a fault during an experiment trips and zeroes first at the device)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from test_reliability_harness import DaemonProcess, MockProcess, read_summary, start_daemon, traceback_free

from furuta_rt.config import load_rig
from furuta_rt.errors import UserError
from furuta_rt.experiment.plan import (
    EVENT_PREFIX,
    Excitation,
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
                       "--summary-json", str(tmp_path / "summary.json"), "--mock-arg=--pacing=lockstep"])
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


def test_run_refuses_a_hanging_plan_before_starting(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """A hanging plan (open loop) is designed and simulated, not run: exit 2, one line naming why, nothing started."""
    from furuta_rt.cli import main

    plan = write_plan(tmp_path, 'mode = "hanging"\n[[segment]]\nkind = "chirp"\namplitude = 0.03\nf0 = 0.4\nf1 = 1.8\n'
                      'duration = 2\n')
    assert load_plan(plan).mode == "hanging"
    rc = main(["run", "--mock", "--experiment", str(plan), "--no-tui", "--log", str(tmp_path / "run.mcap")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "runs plans while balancing" in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "run.mcap").exists()
