"""Every signal that ends `furuta-rt run`, judged at the device: the real daemon (a subprocess in its own
session, signalled as a terminal signals its foreground group) against hil-mock with a recorder on its
device (tests/test_reliability_harness.py: every COMMAND and STOP the device received, every output change).

Each stop signal (SIGINT, SIGQUIT, SIGTERM, SIGHUP, and bursts of them) must: zero the actuator first (the
last frame the device acted on is a STOP or an accepted u = 0), close the log with its footer (the indexed
reader reads it whole), write the summary file, and exit 0 (an operator stop). During start-up the same
signals end the command with one line and 128 + the signal's number, never a traceback.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path

import pytest
from test_reliability_harness import (
    FURUTA_RT,
    ROOT,
    DaemonProcess,
    MockProcess,
    read_summary,
    start_daemon,
    traceback_free,
)

import firmware_protocol as fp
from furuta_rt.io.mcap_read import read_log
from hil_mock.ptyport import open_raw_pty

ENABLE = int(fp.CommandFlags.ENABLE)


def _stop_and_judge(tmp: Path, signals: list[int], *, gap_s: float = 0.02, mock_args: list[str] = (),
                    wait_for: str = "→ balancing") -> tuple[int, object, object]:
    mock = MockProcess(tmp, list(mock_args))
    daemon = start_daemon(tmp, mock.port, duration=60.0)
    try:
        daemon.wait_for_line(wait_for)
        time.sleep(0.3)
        t_signal = time.time_ns()
        for sig in signals:
            daemon.kill_group(sig)
            time.sleep(gap_s)
        rc = daemon.wait()
    finally:
        daemon.kill_group(signal.SIGKILL)
        rec = mock.stop()
    out = daemon.stderr + daemon.stdout
    assert traceback_free(out), out
    # the device: the actuator is at zero and the last host frame it acted on zeroes it (STOP or accepted u = 0)
    rec.assert_ends_safe()
    assert rec.stops and rec.stops[-1][0] > t_signal, "no STOP reached the device after the signal"
    acted = [c for c, ok in zip(rec.commands, rec.accepted, strict=True) if ok]
    last_enable = max((c[0] for c in acted if c[5] & ENABLE), default=0)
    assert rec.stops[-1][0] >= last_enable, "an ENABLE COMMAND took effect after the last STOP"
    return rc, daemon, rec


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGQUIT, signal.SIGTERM, signal.SIGHUP],
                         ids=["SIGINT", "SIGQUIT", "SIGTERM", "SIGHUP"])
def test_each_stop_signal_zeroes_the_device_first_closes_the_log_and_writes_the_summary(tmp_path: Path, sig: int) -> None:
    rc, daemon, _ = _stop_and_judge(tmp_path, [sig])
    assert rc == 0, daemon.stderr
    s = read_summary(tmp_path)
    assert s["end"] == "operator_stop", s
    assert signal.Signals(sig).name in s["trip_message"], s["trip_message"]
    log = read_log(tmp_path / "run.mcap")
    assert not log.recovered, log.warnings  # the footer is there: the indexed reader reads it whole
    assert any("operator stop" in e["message"] for e in log.events), log.events[-3:]
    assert (log.ticks["state"] == "balancing").sum() > 0


@pytest.mark.parametrize("burst", ["SIGINT x6", "SIGTERM x6", "SIGHUP+SIGQUIT+SIGTERM+SIGINT"])
def test_a_burst_of_stop_signals_still_ends_with_the_summary_and_a_closed_log(tmp_path: Path, burst: str) -> None:
    """Repeated Ctrl-C (or a SIGTERM burst, or a closing terminal while the user hits keys) during the stop:
    the second and later signals must not cut the shutdown short (the summary file and the footer)."""
    if "x" in burst:
        name, n = burst.split(" x")
        sigs = [getattr(signal, name)] * int(n)
    else:
        sigs = [getattr(signal, n) for n in burst.split("+")]
    rc, daemon, _ = _stop_and_judge(tmp_path, sigs, gap_s=0.15)  # over about a second
    assert rc == 0, daemon.stderr
    assert read_summary(tmp_path)["end"] == "operator_stop"
    assert not read_log(tmp_path / "run.mcap").recovered


def test_an_operator_stop_before_the_pendulum_balanced_is_not_an_error(tmp_path: Path) -> None:
    """The pendulum never came within the arming window (the mock starts at θ = 0.4 rad); the operator
    stops the run on purpose: exit 0 and no 'error' line (the run did end without balancing: said plainly)."""
    rc, daemon, rec = _stop_and_judge(tmp_path, [signal.SIGINT], mock_args=["--initial-theta", "0.4"],
                                      wait_for="device ")
    assert rc == 0, daemon.stderr
    assert not [line for line in daemon.stderr.splitlines() if "error" in line.lower()], daemon.stderr
    assert "did not balance" in daemon.stderr
    assert not [c for c in rec.commands if c[5] & ENABLE], "the actuator was never enabled"


def _wait_until(pred, timeout: float, what: str) -> None:
    end = time.monotonic() + timeout
    while not pred():
        if time.monotonic() > end:
            raise TimeoutError(what)
        time.sleep(0.005)


def _holds_fd_to(pid: int, path: str) -> bool:
    try:
        return any(os.readlink(f"/proc/{pid}/fd/{fd}") == path for fd in os.listdir(f"/proc/{pid}/fd"))
    except OSError:
        return False


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT],
                         ids=["SIGINT", "SIGTERM", "SIGHUP", "SIGQUIT"])
def test_a_stop_signal_during_the_handshake_is_one_line_and_128_plus_signum(tmp_path: Path, sig: int) -> None:
    """The daemon has opened the port and waits for the device's answer (a pty nobody answers)."""
    master, slave_path = open_raw_pty()
    try:
        proc = subprocess.Popen([*FURUTA_RT, "run", "--port", slave_path, "--no-tui", "--duration", "5"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
                                start_new_session=True)
        try:
            _wait_until(lambda: _holds_fd_to(proc.pid, slave_path) or proc.poll() is not None, 60, "port never opened")
            os.killpg(proc.pid, sig)
            out, err = proc.communicate(timeout=60)
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
    finally:
        os.close(master)
    assert proc.returncode == 128 + sig, err
    assert traceback_free(err + out), err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "interrupted" in lines[0] and signal.Signals(sig).name in lines[0], err


@pytest.mark.parametrize("command", [["run", "--mock", "--no-tui", "--duration", "5"], ["diagnose", "nonexistent.csv"]],
                         ids=["run", "diagnose"])
def test_ctrl_c_while_the_modules_load_is_one_line_not_a_traceback(command: list[str]) -> None:
    """SIGINT as soon as numpy is being loaded (the command modules' imports, before any work)."""
    proc = subprocess.Popen([*FURUTA_RT, *command], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            cwd=ROOT, start_new_session=True)

    def loading_numpy() -> bool:
        try:
            return "numpy" in Path(f"/proc/{proc.pid}/maps").read_text() or proc.poll() is not None
        except OSError:
            return proc.poll() is not None

    try:
        _wait_until(loading_numpy, 60, "numpy never loaded")
        os.killpg(proc.pid, signal.SIGINT)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert traceback_free(err + out), err
    assert proc.returncode == 130, err
    assert len(err.strip().splitlines()) == 1 and "interrupted" in err, err


@pytest.mark.parametrize("sig", [signal.SIGHUP, signal.SIGINT, signal.SIGQUIT], ids=["SIGHUP", "SIGINT", "SIGQUIT"])
def test_run_mock_the_device_outlives_a_terminal_signal_and_gets_the_stop(tmp_path: Path, sig: int) -> None:
    """`run --mock` from a terminal: the signal reaches the whole foreground group. hil-mock (a child of the daemon)
    must not die or stop serving before the daemon's u = 0 and STOP reach it. Judged by the device's own count:
    a host that closes the port while the device still streams is a hang-up (the device zeroed itself); a STOP
    first leaves the device idle, so the port closing is no hang-up. hil-mock killed by the signal writes no
    statistics at all."""
    stats = tmp_path / "mock.json"
    daemon = DaemonProcess(["--mock", "--no-tui", "--duration", "60", "--log", str(tmp_path / "run.mcap"),
                            "--summary-json", str(tmp_path / "summary.json"), f"--mock-arg=--stats-json={stats}"])
    try:
        daemon.wait_for_line("→ balancing")
        time.sleep(0.3)
        daemon.kill_group(sig)
        rc = daemon.wait()
    finally:
        daemon.kill_group(signal.SIGKILL)
    assert traceback_free(daemon.stderr + daemon.stdout), daemon.stderr
    assert rc == 0, daemon.stderr
    assert read_summary(tmp_path)["end"] == "operator_stop"
    assert stats.exists(), f"hil-mock wrote no statistics: it died of the {signal.Signals(sig).name}"
    device = json.loads(stats.read_text())
    assert device["handshakes"] == 1 and device["watchdog_trips"] == 0, device
    assert device["hangups"] == 0, "the port closed while the device streamed: it never got the STOP"
    assert not read_log(tmp_path / "run.mcap").recovered
