"""Issue 10, items 2-5: the real daemon (``furuta-rt run --port``) against hil_mock over a real pty.

The mock is hil-mock itself with a recorder on its device (tests/test_reliability_harness.py): every
COMMAND the device received, every change of its actuator output, resets and hang-ups, and which
SAMPLE frames left it intact. Faults come from the mock (byte corruption/loss, reset, disconnect) or
from real signals sent to the daemon (SIGSTOP/SIGCONT). Limits: see TEST_SAFETY in the harness.
"""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import pytest
from test_reliability_harness import (
    HIL_RATE,
    TEST_SAFETY,
    MockProcess,
    MockRecord,
    read_summary,
    start_daemon,
    traceback_free,
)

import firmware_protocol as fp
from furuta_rt.io.mcap_read import LogData, read_log

pytestmark = pytest.mark.hil
ENABLE = int(fp.CommandFlags.ENABLE)
PERIOD_NS = 1_000_000_000 // HIL_RATE


def _one_line_errors(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if "error" in line.lower()]


def _assert_ends_safe(rec: MockRecord) -> None:
    """The device's actuator is at zero, and the last frame of the host it acted on zeroes it."""
    rec.assert_ends_safe()


def test_corrupted_and_dropped_bytes_keep_balancing(tmp_path: Path) -> None:
    """Item 2: 10⁻³ per byte corrupted and 10⁻³ dropped, both directions; the run completes its duration,
    counts the errors, balances throughout, and logs only SAMPLEs that reached the host intact. The mock runs in
    lockstep (a lost COMMAND holds the device 0.1 s, then it ticks on): how well it balances is then the loop's, not
    the load's (a host stall of a few hundred ms in real time leaves the pendulum unactuated that long)."""
    rates = ["--corrupt-rate", "1e-3", "--drop-rate", "1e-3", "--rx-corrupt-rate", "1e-3", "--rx-drop-rate", "1e-3"]
    mock = MockProcess(tmp_path, [*rates, "--seed", "3", "--pacing", "lockstep"])
    daemon = start_daemon(tmp_path, mock.port, duration=3.0)
    rc = daemon.wait()
    rec = mock.stop()
    assert traceback_free(daemon.stderr + daemon.stdout), daemon.stderr
    assert rc == 0, f"exit {rc}: {daemon.stderr}\n{daemon.stdout}"
    s = read_summary(tmp_path)
    assert s["end"] == "duration" and s["final_state"] != "tripped"
    assert s["crc_errors"] > 0 and s["seq_gaps"] > 0, "host-side errors are counted"
    assert s["balanced_s"] > 2.5
    st = rec.stats
    assert st["tx_bytes_corrupted"] > 10 and st["tx_bytes_dropped"] > 10
    assert st["rx_bytes_corrupted"] > 3 and st["crc_errors"] + st["frame_errors"] > 0, "device-side errors counted"
    assert rec.samples_damaged, "the mock damaged SAMPLE frames"
    log = read_log(tmp_path / "run.mcap")
    assert not log.recovered and log.n_ticks == s["ticks"]
    intact = {seq for _, seq in rec.samples_intact}
    logged = set(log.ticks["seq"].tolist())
    assert logged <= intact, f"ticks logged from damaged frames: {sorted(logged - intact)[:5]}"
    assert {seq for _, seq in rec.samples_damaged}.isdisjoint(logged)
    balancing = log.ticks["state"] == "balancing"
    assert balancing.mean() > 0.95 and abs(log.ticks["theta"][balancing]).max() < 0.1, "kept balancing"
    sent = {c[3] for c in rec.commands}
    assert sent <= intact, "every COMMAND the device received answers an intact SAMPLE"
    assert st["watchdog_trips"] == 0
    _assert_ends_safe(rec)


def _trip_events(log: LogData) -> list[dict]:
    return [e for e in log.events if "→ tripped" in str(e.get("message", ""))]


def test_device_reset_trips_and_a_new_run_handshakes_again(tmp_path: Path) -> None:
    """Item 3: the device reboots mid-run (output zero, idle; its seq restarts only after a new HELLO).
    The daemon sees the stream stop: link-loss trip, exit 1, one error line, and nothing it sends
    afterwards re-enables the actuator. The operator re-arms by starting a new run: it handshakes again
    (seq from 0) and balances. Item 4 on that second run: the device vanishes (pty closed) → the daemon
    trips at once on EOF/EIO (not by timeout), exit 1, one error line, a complete log."""
    first, second = tmp_path / "first", tmp_path / "second"
    first.mkdir()
    second.mkdir()
    mock = MockProcess(tmp_path, [])
    d1 = start_daemon(first, mock.port, duration=30.0)
    d1.wait_for_line("→ balancing")
    time.sleep(0.5)
    mock.reset()
    rc1 = d1.wait()
    assert traceback_free(d1.stderr + d1.stdout), d1.stderr
    assert rc1 == 1, d1.stderr
    s1 = read_summary(first)
    assert s1["end"] == "trip" and s1["trip_reason"] == "link_loss", s1["trip_message"]
    assert "no SAMPLE" in s1["trip_message"]
    errors = _one_line_errors(d1.stderr)
    assert len(errors) == 1 and "link loss" in errors[0], d1.stderr
    log1 = read_log(first / "run.mcap")
    assert not log1.recovered, log1.warnings
    assert (log1.ticks["state"] == "balancing").sum() > 0.4 * HIL_RATE
    assert len(_trip_events(log1)) == 1 and "link loss" in _trip_events(log1)[0]["message"]
    # second run on the same device: a fresh handshake, then the device vanishes
    d2 = start_daemon(second, mock.port, duration=30.0)
    d2.wait_for_line("→ balancing")
    time.sleep(0.5)
    mock.disconnect()
    rc2 = d2.wait()
    rec = mock.stop()
    assert traceback_free(d2.stderr + d2.stdout), d2.stderr
    assert rc2 == 1, d2.stderr
    s2 = read_summary(second)
    assert s2["end"] == "trip" and s2["trip_reason"] == "link_loss", s2["trip_message"]
    assert "no SAMPLE" not in s2["trip_message"], "a closed port is noticed at once, not by the SAMPLE timeout"
    errors = _one_line_errors(d2.stderr)
    assert len(errors) == 1, d2.stderr
    log2 = read_log(second / "run.mcap")
    assert not log2.recovered, log2.warnings
    assert log2.ticks["seq"][0] < 10, "the new session's seq starts again from 0"
    assert (log2.ticks["state"] == "balancing").sum() > 0.4 * HIL_RATE
    # device side: the reset zeroed the output, and nothing the host sent afterwards re-enabled it
    (t_reset,) = [t for t, _, what in rec.events if what == "reset"]
    assert rec.output_at(t_reset + 1_000_000) == 0.0  # reboot: zero at once (recorded µs later)
    hellos = [t for t, _, what in rec.events if what == "hello"]  # a slow ACK may bring a second HELLO per run
    assert hellos[0] < t_reset, "the first run handshook before the reset"
    rehello = next(t for t in hellos if t > t_reset)
    between = [o for o in rec.outputs if t_reset < o[0] < rehello]
    assert all(u == 0.0 for _, _, u in between), "the actuator stayed at zero from the reset to the next handshake"
    # disconnect: the trip follows the pty closing, from the closed port itself (its message is not the SAMPLE
    # timeout's, above) and so before that timeout could have run out; on an idle machine within two periods, on a
    # loaded one when the host is next scheduled (the loaded box stalls processes for hundreds of ms now and then)
    t_disc = next(t for t, _, what in rec.events if what == "hangup" and t > rehello)
    (trip,) = _trip_events(log2)
    delay_s = (trip["log_time"] - t_disc) * 1e-9
    link_timeout_s = TEST_SAFETY["link_loss_periods"] / HIL_RATE
    assert -0.005 < delay_s < link_timeout_s, f"tripped {delay_s * 1e3:.1f} ms after the disconnect"
    assert rec.final_output == 0.0


def test_host_stall_device_watchdog_zeroes_and_daemon_trips_after_sigcont(tmp_path: Path) -> None:
    """Item 5: SIGSTOP the daemon's control process for 100 ms while balancing. The device watchdog
    (40 ms) zeroes the actuator within its timeout; after SIGCONT the daemon finds stale SAMPLEs
    (and the device's WATCHDOG_TRIPPED) and trips; it never enables the actuator again."""
    watchdog_ms = 40
    mock = MockProcess(tmp_path, [])
    daemon = start_daemon(tmp_path, mock.port, duration=30.0, watchdog_ms=watchdog_ms)
    daemon.wait_for_line("→ balancing")
    time.sleep(0.5)
    t_stop = time.time_ns()
    os.kill(daemon.pid, signal.SIGSTOP)
    time.sleep(0.1)
    t_cont = time.time_ns()
    os.kill(daemon.pid, signal.SIGCONT)
    rc = daemon.wait()
    rec = mock.stop()
    assert traceback_free(daemon.stderr + daemon.stdout), daemon.stderr
    assert rc == 1, daemon.stderr
    s = read_summary(tmp_path)
    assert s["end"] == "trip" and s["trip_reason"] in ("device_fault", "overruns"), s["trip_message"]
    assert len(_one_line_errors(daemon.stderr)) == 1, daemon.stderr
    # device: the watchdog fired and the output was zero within watchdog + 2 periods (+ tick granularity) of
    # the last COMMAND it received before the daemon stopped (a pty may deliver that one late on a busy box)
    assert rec.stats["watchdog_trips"] >= 1
    t_last = max(c[0] for c in rec.commands if c[0] < t_cont)
    deadline = t_last + (watchdog_ms + 3) * 1_000_000 + 2 * PERIOD_NS
    assert deadline < t_cont, "the device was still within its watchdog when the daemon resumed"
    assert rec.output_at(deadline) == 0.0, "the device watchdog did not zero the actuator in time"
    before = [o for o in rec.outputs if o[0] < t_stop]
    assert any(u != 0.0 for _, _, u in before), "it was balancing (non-zero torque) before the stall"
    after = [o for o in rec.outputs if o[0] > deadline]
    assert all(u == 0.0 for _, _, u in after), f"the actuator moved again after the stall: {after[:3]}"
    late = rec.commands_after(t_cont)
    assert not [c for c in late if c[5] & ENABLE], "the daemon sent ENABLE after SIGCONT (acted on stale samples)"
    _assert_ends_safe(rec)
    log = read_log(tmp_path / "run.mcap")
    assert not log.recovered and log.ticks["state"][-1] == "tripped" and log.ticks["u"][-1] == 0.0
