"""HIL tests of `furuta-rt run`: the real daemon, as a user starts it, against hil_mock over a real pty.

* the README's main job (``--mock``, 10 s at 500 Hz) balances, and so do the other compensation modes (4 s
  each), the mock in lockstep; each run prints its timing summary, and its log holds every tick, read back by an
  independent MCAP reader (@mcap/core's McapStreamReader under node, see tests/test_reliability_harness.py) and
  replayed bit for bit;
* the thesis' effect: arm Coulomb friction in the mock and no compensation → a limit cycle (as in the
  simulation of the same loop); Coulomb compensation matched to the mock's Fc → std θ and std φ fall ≥ 5×;
* trips on |θ| > limit, on link loss, and the operator's SIGINT, each ending with u = 0 as the last
  COMMAND the device received (the recording mock of the reliability tests sees every COMMAND);
* a run killed with SIGKILL leaves a log readable up to about its last second.

The balance runs and the friction comparison run the mock in lockstep pacing (each device tick waits for the
COMMAND of the previous one): the physics is then the same whatever the load of the machine, so how well it
balances and the ratios are those of the loop, not of the CI box (in real time a host stall of a few hundred ms,
seen on a loaded 2-core machine, left the pendulum unactuated long enough to trip). The trips, the stops and the
killed run are real time.
"""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import numpy as np
import pytest
from test_reliability_harness import (
    LOCKSTEP,
    DaemonProcess,
    MockProcess,
    MockRecord,
    independent_mcap_counts,
    read_summary,
    start_daemon,
    traceback_free,
)

import firmware_protocol as fp
from furuta_rt.config import RigConfig, load_rig
from furuta_rt.io import log_schema as ls
from furuta_rt.io.mcap_read import LogData, read_log
from furuta_rt.io.rig_toml import rig_to_toml
from furuta_rt.model.effects import effects_from_assignments
from furuta_rt.replay.core import replay_log
from furuta_rt.sim.closed_loop import run_closed_loop

pytestmark = pytest.mark.hil
RATE = 500
FRICTION = "arm_coulomb.Fc=0.3"  # the thesis rig's arm friction, which its [compensation] parameters match
ENABLE = int(fp.CommandFlags.ENABLE)
KILL_LOSS_BOUND_S = 1.6
"""Log lost to a SIGKILL: the logger ends a chunk every 0.5 s (plus the loop's 0.1 s batches and the logger's
0.2 s queue poll) given the CPU; the daemon's run-queue wait (the time a loaded machine held it back) comes on top."""


def mock_run(tmp: Path, name: str, seconds: float, *extra: str) -> DaemonProcess:
    """``furuta-rt run --mock`` exactly as the README runs it, plus a log and a summary JSON."""
    d = tmp / name
    d.mkdir()
    return DaemonProcess(["--mock", "--duration", f"{seconds:g}", "--no-tui", "--log", str(d / "run.mcap"),
                          "--summary-json", str(d / "summary.json"), *extra])


def steady(log: LogData, after_s: float) -> dict[str, np.ndarray]:
    """Tick columns while balancing, from ``after_s`` seconds after balancing began."""
    t = log.ticks
    bal = t["state"] == "balancing"
    t0 = t["t"][np.flatnonzero(bal)[0]]
    keep = bal & (t["t"] >= t0 + after_s)
    return {k: v[keep] for k, v in t.items()}


def assert_ends_safe(rec: MockRecord) -> None:
    """The device's actuator output is zero, and the last frame of the host it acted on zeroes it (an
    accepted u = 0 with ENABLE clear, or STOP)."""
    rec.assert_ends_safe()


# The README's job (`run --mock --duration 10`, the config's mode "none") runs its 10 s; the other modes 4 s each:
# 3 s of balancing after the first second is plenty for the same checks.
MODE_SECONDS = {"none": 10, "coulomb": 4, "stiction": 4, "lugre": 4}


def test_main_job_balances_in_every_compensation_mode(tmp_path: Path) -> None:
    """`furuta-rt run --mock --duration S --no-tui --log out.mcap`, once per --comp mode against the mock
    with the thesis rig's arm friction, paced in lockstep (the device's time, not the machine's load, decides
    what the pendulum does): exit 0, the timing summary, and one tick message per tick."""
    for mode, seconds in MODE_SECONDS.items():  # one after the other: each loop has a core
        ticks = seconds * RATE
        d = mock_run(tmp_path, mode, seconds, "--comp", mode, "--mock-effect", FRICTION, LOCKSTEP)
        rc = d.wait(timeout=120)
        assert traceback_free(d.stderr + d.stdout), d.stderr
        assert rc == 0, f"{mode}: exit {rc}\n{d.stderr}\n{d.stdout}"
        for needle in ("duration reached", "period jitter", "latency sample→command", "overruns", "std θ"):
            assert needle in d.stdout, f"{mode}: no {needle!r} in the summary:\n{d.stdout}"
        s = read_summary(tmp_path / mode)
        # --duration is device time: the run ends when the device clock has run `seconds`; a period with no tick
        # in the run is a SAMPLE lost on the link (a seq gap) or one the device skipped on its own overrun, both
        # counted in the summary (the host logs every SAMPLE it reads, stale ones included)
        missing = ticks - s["ticks"]
        assert s["end"] == "duration" and s["mode"] == mode, s
        assert 0 <= missing <= s["seq_gaps"] + s["device_skipped_periods"], (mode, s["ticks"], s["seq_gaps"],
                                                                              s["device_skipped_periods"])
        ticks = s["ticks"]  # every tick the run reports is in the log, once
        # the update's p99 is our own computing (the daemon runs SCHED_FIFO): within half a period on any load; the
        # period jitter is the machine's (another real-time process on the cores moves it) — scripts/bench measures it
        assert s["balanced_s"] > ticks / RATE - 0.1 and s["update_us"]["p99"] < 1000
        path = tmp_path / mode / "run.mcap"
        counts = independent_mcap_counts(path)
        assert counts["error"] is None and counts["complete"], counts
        topics = counts["topics"]
        assert topics[ls.TICK_TOPIC] == topics[ls.TIMING_TOPIC] == topics[ls.JOINT_STATES_TOPIC] == ticks, counts
        log = read_log(path)
        assert not log.recovered and log.n_ticks == ticks and log.mode == mode
        seq_steps = np.diff(log.ticks["seq"])
        assert np.all(seq_steps >= 1) and (np.all(seq_steps == 1) or s["seq_gaps"] > 0 or missing > 0), mode
        bal = steady(log, 1.0)
        print(f"{mode}: balanced {s['balanced_s']:.3f} s of {seconds} s, |θ| max {np.abs(bal['theta']).max():.4f} rad "
              f"from 1 s, jitter p50 {s['jitter_us']['p50']:.0f} us, update p99 {s['update_us']['p99']:.0f} us")
        assert np.abs(bal["theta"]).max() < 0.1, f"{mode}: |θ| reached {np.abs(bal['theta']).max():.3f} rad"
        assert replay_log(log).exact, f"{mode}: the logged ticks do not replay to the logged u"


def friction_rig(tmp: Path) -> tuple[RigConfig, Path]:
    """The thesis rig with its Coulomb compensation matched to the mock's arm friction (Fc = 0.3 N m,
    ε = 0.01 rad/s, the smoothing band of eq. 1's sign)."""
    rig = load_rig("thesis")
    coulomb = rig.compensation.coulomb.model_copy(update={"Fc": 0.3, "epsilon": 0.01})
    comp = rig.compensation.model_copy(update={"coulomb": coulomb})
    rig = rig.model_copy(update={"compensation": comp})
    path = tmp / "rig_friction.toml"
    path.write_text(rig_to_toml(rig))
    return rig, path


def _dominant(x: np.ndarray, dt: float) -> tuple[float, float]:
    """(frequency Hz, share of the variance) of the strongest spectral line of ``x``."""
    x = x - x.mean()
    power = np.abs(np.fft.rfft(x)) ** 2
    f = np.fft.rfftfreq(len(x), dt)
    k = int(power[1:].argmax()) + 1
    return float(f[k]), float(power[k - 1 : k + 2].sum() / power[1:].sum())


def test_arm_friction_limit_cycle_and_matched_coulomb_compensation(tmp_path: Path) -> None:
    """Thesis section 7 through the wire: with Fc = 0.3 N m on the arm and no compensation the loop
    settles into a limit cycle (the φ oscillation the simulation of the same loop predicts); Coulomb
    compensation matched to Fc cuts std θ and std φ by at least 5×."""
    rig, rig_path = friction_rig(tmp_path)
    seconds = 15.0
    common = ["--config", str(rig_path), "--mock-effect", FRICTION, LOCKSTEP]
    runs = {m: mock_run(tmp_path, m, seconds, "--comp", m, *common) for m in ("none", "coulomb")}  # concurrently
    stats = {}
    for mode, d in runs.items():
        rc = d.wait(timeout=120)
        assert rc == 0 and traceback_free(d.stderr), f"{mode}: exit {rc}\n{d.stderr}\n{d.stdout}"
        log = read_log(tmp_path / mode / "run.mcap")
        assert log.n_ticks == seconds * RATE and replay_log(log).exact
        st = steady(log, 3.0)
        stats[mode] = (float(np.std(st["theta"])), float(np.std(st["phi"])), st["phi"])
    (th0, ph0, phi0), (th1, ph1, _) = stats["none"], stats["coulomb"]
    # the limit cycle: a large, nearly sinusoidal arm oscillation, as simulated for the same loop
    f_hil, share = _dominant(phi0, 1.0 / RATE)
    sim = run_closed_loop(rig, seconds, effects=effects_from_assignments([FRICTION]), mode="none")
    sim_phi = sim.phi[int(3.0 * RATE) :]
    f_sim, _ = _dominant(sim_phi, 1.0 / RATE)
    assert ph0 > 0.2 and share > 0.8, f"no limit cycle: std φ {ph0:.3f} rad, dominant line {share:.0%}"
    assert abs(f_hil - f_sim) < 0.1 and ph0 == pytest.approx(float(np.std(sim_phi)), rel=0.2)
    # matched Coulomb compensation
    assert th0 / th1 >= 5.0 and ph0 / ph1 >= 5.0, f"std θ {th0:.5f} → {th1:.5f}, std φ {ph0:.4f} → {ph1:.4f}"
    # the run's own summary says what happened: the limit cycle at the frequency of the log's φ, its amplitude
    # the log's, and the effect the mock was given; with the matched compensation none of that size
    lc = read_summary(tmp_path / "none")["limit_cycle_phi"]
    x = phi0 - phi0.mean()
    acf = np.array([np.dot(x[:-k], x[k:]) / (len(x) - k) for k in range(1, len(x) // 2)])
    first_peak = int(np.argmax(np.where(np.arange(1, len(x) // 2) > RATE, acf, -np.inf))) + 1  # beyond 1 s
    assert lc is not None and lc["period"] == pytest.approx(first_peak / RATE, rel=0.03)
    assert lc["amplitude"] == pytest.approx(0.5 * float(np.ptp(phi0)), rel=0.1)
    assert "limit cycle: φ ±" in runs["none"].stdout and f"mock injected: {FRICTION}" in runs["none"].stdout
    lc1 = read_summary(tmp_path / "coulomb")["limit_cycle_phi"]
    assert lc1 is None or lc1["amplitude"] < 0.2 * lc["amplitude"]


def test_trip_on_theta_limit_ends_with_zero(tmp_path: Path) -> None:
    """Zero gains: armed near upright, the pendulum falls; |θ| > 0.5 rad trips, exit 1, u = 0 last."""
    mock = MockProcess(tmp_path, [])
    d = start_daemon(tmp_path, mock.port, duration=30.0, extra=["--gains", "0,0,0,0"])
    rc = d.wait(timeout=120)
    rec = mock.stop()
    assert rc == 1 and traceback_free(d.stderr), d.stderr
    s = read_summary(tmp_path)
    assert s["trip_reason"] == "theta_limit" and "beyond the limit 0.5 rad" in s["trip_message"]
    assert "TRIPPED (theta_limit)" in d.stdout
    errors = [line for line in d.stderr.splitlines() if "error" in line]
    assert len(errors) == 1 and "→ tripped" in errors[0], d.stderr
    log = read_log(tmp_path / "run.mcap")
    assert log.ticks["state"][-1] == "tripped" and abs(log.ticks["theta"][-1]) > 0.5 and log.ticks["u"][-1] == 0.0
    assert_ends_safe(rec)


def test_trip_on_link_loss_ends_with_zero(tmp_path: Path) -> None:
    """The device→host direction goes silent for 0.5 s while balancing: no SAMPLE for longer than the
    link timeout trips with link_loss, and the zero COMMAND still reaches the device."""
    mock = MockProcess(tmp_path, ["--fault", "mute@2:500ms"])
    d = start_daemon(tmp_path, mock.port, duration=30.0, extra=["--link-timeout-ms", "60"])
    rc = d.wait(timeout=120)
    rec = mock.stop()
    assert rc == 1 and traceback_free(d.stderr), d.stderr
    s = read_summary(tmp_path)
    assert s["trip_reason"] == "link_loss" and "no SAMPLE" in s["trip_message"], s["trip_message"]
    assert s["balanced_s"] > 1.0
    assert_ends_safe(rec)


def test_sigint_stops_cleanly_with_zero_log_closed_summary_printed(tmp_path: Path) -> None:
    mock = MockProcess(tmp_path, [])
    d = start_daemon(tmp_path, mock.port, duration=None)
    d.wait_for_line("→ balancing")
    time.sleep(1.0)
    os.kill(d.pid, signal.SIGINT)
    rc = d.wait(timeout=60)
    rec = mock.stop()
    assert rc == 0 and traceback_free(d.stderr + d.stdout), d.stderr
    assert "stopped by the operator" in d.stdout and "period jitter" in d.stdout
    s = read_summary(tmp_path)
    assert s["end"] == "operator_stop" and s["balanced_s"] > 0.9
    log = read_log(tmp_path / "run.mcap")
    assert not log.recovered and log.n_ticks == s["ticks"], log.warnings
    assert any("operator stop (SIGINT)" in str(e["message"]) for e in log.events)
    assert_ends_safe(rec)
    enabled = [i for i, c in enumerate(rec.commands) if c[5] & ENABLE]
    # after the last enabled COMMAND: the loop's own u = 0, then stop()'s zero COMMAND sent twice (+ slack of one)
    assert enabled and len(rec.commands) - enabled[-1] <= 4, "it was balancing until the signal"


def test_killed_run_leaves_a_log_readable_to_its_last_second(tmp_path: Path) -> None:
    """SIGKILL to the daemon and its logger at once: the chunks flushed every half second remain. The loss is the kill's
    wall time against the log's last tick, stamped on the device's clock mapped to the wall clock (the log's time
    base), so ticks the machine's load kept from happening are not counted as lost."""
    d = mock_run(tmp_path, "killed", 60.0)
    d.wait_for_line("→ balancing")
    waited_s = -d.run_queue_wait_s()
    time.sleep(3.0)
    waited_s += d.run_queue_wait_s()
    t_kill, t0 = time.time_ns(), time.monotonic()
    d.kill_group(signal.SIGKILL)
    kill_s = time.monotonic() - t0  # the kill landed within this much after t_kill (the daemon ran on meanwhile)
    d.wait(timeout=30)
    path = tmp_path / "killed" / "run.mcap"
    log = read_log(path)
    assert log.recovered and log.rig is not None and log.gains is not None
    assert (log.ticks["state"] == "balancing").sum() > 1.0 * RATE, "seconds of balancing were recorded"
    lost_s = (t_kill - int(log.tick_log_time[-1])) * 1e-9
    assert -kill_s <= lost_s < KILL_LOSS_BOUND_S + waited_s + kill_s, (
        f"the log lost the last {lost_s:.2f} s before the kill ({waited_s:.2f} s of run-queue wait)")
    counts = independent_mcap_counts(path)
    assert counts["tick_records"] == log.n_ticks, counts  # the tick batches, decoded by the independent reader
    # the JSON ticks (Foxglove's) follow their batch's chunk: the kill may fall between the two chunks' writes
    assert log.n_ticks - ls.BATCH_TICKS <= counts["topics"][ls.TICK_TOPIC] <= log.n_ticks, counts


def test_ctrl_c_in_a_terminal_stops_the_mock_run_cleanly(tmp_path: Path) -> None:
    """Ctrl-C in a terminal signals the whole process group: the daemon and its logger (hil-mock runs in a session
    of its own and waits for the daemon's STOP: tests/test_signals.py); an operator stop."""
    d = mock_run(tmp_path, "ctrl_c", 60.0)
    d.wait_for_line("→ balancing")
    time.sleep(1.0)
    d.kill_group(signal.SIGINT)
    rc = d.wait(timeout=60)
    assert rc == 0 and traceback_free(d.stderr + d.stdout), d.stderr
    assert "stopped by the operator" in d.stdout
    s = read_summary(tmp_path / "ctrl_c")
    assert s["end"] == "operator_stop"
    log = read_log(tmp_path / "ctrl_c" / "run.mcap")
    assert not log.recovered and log.n_ticks == s["ticks"]
    assert any("operator stop (SIGINT)" in str(e["message"]) for e in log.events)
