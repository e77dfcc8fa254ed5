"""The terminal dashboard (issue 18): `furuta-rt run --mock` in a real terminal (a pty, as a user's
terminal is) draws traces of θ, φ and u, a hint of what the state waits for or what trips it, the log
file, "Ctrl-C to stop", and a live limit-cycle line whose amplitude and period agree with the log of
the same run. The hints of the other states are checked on the rendered panel."""

from __future__ import annotations

import fcntl
import itertools
import math
import os
import pty
import re
import shutil
import struct
import subprocess
import termios
import threading
from pathlib import Path
from typing import Any

import pytest
from rich.console import Console
from test_reliability_harness import FURUTA_RT, ROOT, traceback_free

from furuta_rt.io.mcap_read import read_log
from furuta_rt.runtime.dashboard import Dashboard, DashboardInfo, render
from furuta_rt.stats import limit_cycle_stats

ANSI = re.compile(r"\x1b\[[0-9;?]*[A-Za-z]|\x1b[()][A-Z0-9]|\r")
BARS = set("▁▂▃▄▅▆▇█")


def _snap(state: str, theta: float = 0.0, trip: str = "") -> dict:
    return dict(elapsed=1.0, state=state, mode="none", theta=theta, phi=0.0, u=0.0, u_comp=0.0, fc_hat=0.0,
                rate_hz=500.0, jitter_max_us=10.0, overruns=0, late_commands=0, seq_gaps=0, crc_errors=0,
                dropped=0, ticks=500, trip=trip, events=[])


def _text(panel: object) -> str:
    console = Console(record=True, width=130)
    console.print(panel)
    return console.export_text()


def test_each_state_says_what_arms_or_trips_the_loop() -> None:
    info = DashboardInfo(log_path="lab/run7.mcap", arm_theta=0.1, theta_limit=0.5, phi_limit=18.85)
    board = Dashboard(info)
    idle = _text(board.render(_snap("idle", theta=3.1225)))
    assert "within |θ| < 0.1 rad" in idle and "+3.123 rad" in idle
    assert "|θ| > 0.5 rad" in _text(board.render(_snap("balancing")))
    assert "theta_limit" in _text(board.render(_snap("tripped", trip="theta_limit")))
    for text in (idle, _text(board.render(None))):
        assert "log: lab/run7.mcap" in text and "Ctrl-C to stop" in text
    assert "log: none (--log FILE.mcap to record)" in _text(render(_snap("armed")))


def _run_in_pty(args: list[str], cols: int = 130, rows: int = 60, prefix: list[str] | None = None,
                preexec_fn: Any = None) -> tuple[int, str, str]:
    """Run the CLI with its stdout on a new pty of ``cols`` × ``rows``; (exit code, what the terminal got, stderr)."""
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", rows, cols, 0, 0))
    env = {**os.environ, "TERM": "xterm-256color", "COLUMNS": str(cols), "LINES": str(rows)}
    proc = subprocess.Popen([*(prefix or []), *FURUTA_RT, "run", *args], stdin=slave, stdout=slave,
                            stderr=subprocess.PIPE, cwd=ROOT, env=env, start_new_session=True, preexec_fn=preexec_fn)
    os.close(slave)
    chunks: list[bytes] = []

    def pump() -> None:
        while True:
            try:
                data = os.read(master, 65536)
            except OSError:  # EIO: every holder of the slave end is gone
                return
            if not data:
                return
            chunks.append(data)

    reader = threading.Thread(target=pump, daemon=True)
    reader.start()
    _, err = proc.communicate(timeout=120)
    reader.join(10)
    os.close(master)
    return proc.returncode, b"".join(chunks).decode(errors="replace"), err.decode(errors="replace")


@pytest.mark.hil
def test_dashboard_in_a_terminal_shows_the_motion_and_the_limit_cycle(tmp_path: Path) -> None:
    log_path = tmp_path / "demo.mcap"
    rc, screen, err = _run_in_pty(["--mock", "--duration", "10", "--mock-effect", "arm_coulomb.Fc=0.3",
                                   "--log", str(log_path), "--tui"])
    assert rc == 0 and traceback_free(err + screen), err
    text = ANSI.sub("", screen)
    frames = text.split("Ctrl-C to stop")
    # a frame per snapshot it got (the loop sends 10 a second of the run, skipping those a dashboard still busy has
    # no room for), in the run's order, from its first second to its last, never still for 2 s of it: redrawn live
    times = [float(m.group(1)) for f in frames if (m := re.search(r"time +([\d.]+) s", f))]
    assert times == sorted(times) and times[0] < 1.0 and times[-1] > 9.0, times
    assert len(set(times)) - 1 <= 10.5 * (times[-1] - times[0]), f"more redraws than snapshots: {times}"
    assert max(b - a for a, b in itertools.pairwise(times)) < 2.0, f"the dashboard stood still: {times}"
    last = frames[-2]  # the last frame drawn (what stays on the terminal)
    assert "BALANCING" in last and f"log: {log_path}" in last
    assert "balancing: trips on |θ| > 0.5 rad" in last
    traces = {}
    for line in last.splitlines():
        m = re.match(r"^[│ ]*([θφu]) ([▁▂▃▄▅▆▇█]+) ([+-][\d.]+) … ([+-][\d.]+)", line)
        if m:
            traces[m.group(1)] = (m.group(2), float(m.group(3)), float(m.group(4)))
    assert set(traces) == {"θ", "φ", "u"}, last
    for bars, lo, hi in traces.values():
        assert len(bars) >= 40 and len(set(bars) & BARS) >= 4 and hi > lo  # a moving trace, not a flat line
    log = read_log(log_path)
    bal = log.ticks["state"] == "balancing"
    t, phi = log.ticks["t"][bal], log.ticks["phi"][bal]
    recent = t >= t[-1] - 10.0
    assert traces["φ"][1] == pytest.approx(phi[recent].min(), abs=0.05)
    assert traces["φ"][2] == pytest.approx(phi[recent].max(), abs=0.05)
    m = re.search(r"limit cycle: φ ±([\d.]+) rad, period ([\d.]+) s", last)
    assert m, last
    lc = limit_cycle_stats(t, phi)  # the full-rate log of the same run
    assert lc is not None
    assert float(m.group(1)) == pytest.approx(lc.amplitude, rel=0.1)
    assert float(m.group(2)) == pytest.approx(lc.period, rel=0.1)


def test_a_still_hanging_pendulum_is_a_flat_trace() -> None:
    """θ = ±π is one position: a pendulum hanging still (noise across the seam) is drawn flat, as the angle from
    hanging, not as swings between the trace's ends."""
    board = Dashboard(DashboardInfo())
    for k in range(500):
        side = 1.0 if k % 2 else -1.0
        board.add({**_snap("calibrating", theta=side * (math.pi - 2e-4)), "elapsed": k * 0.02})
    text = _text(board.render({**_snap("calibrating", theta=math.pi - 2e-4), "elapsed": 10.0}))
    row = next(line for line in text.splitlines() if "θ−π" in line and "from hanging" in line)
    assert len(set(row) & BARS) <= 2, row  # one level (two where noise sits on a level boundary): still
    swinging = Dashboard(DashboardInfo())
    for k in range(500):
        swinging.add({**_snap("swinging_up", theta=math.pi + 0.5 * math.sin(k * 0.1)), "elapsed": k * 0.02})
    text = _text(swinging.render({**_snap("swinging_up", theta=math.pi), "elapsed": 10.0}))
    row = next(line for line in text.splitlines() if "θ−π" in line)
    assert len(set(row) & BARS) >= 6 and "-0.500" in row and "+0.500" in row, row


def _as_a_user_without_realtime_rights() -> None:
    """A root test process drops what lets it lock memory and use SCHED_FIFO (as a non-root user has neither)."""
    import resource

    resource.setrlimit(resource.RLIMIT_MEMLOCK, (65536, 65536))
    resource.setrlimit(resource.RLIMIT_RTPRIO, (0, 0))


@pytest.mark.hil
def test_in_a_terminal_without_realtime_rights_each_warning_shows_once_and_hanging_is_flat() -> None:
    if os.geteuid() == 0:
        if shutil.which("setpriv") is None:
            pytest.skip("running as root without setpriv: cannot drop the realtime capabilities")
        prefix = ["setpriv", "--inh-caps=-all", "--bounding-set=-ipc_lock,-sys_nice,-sys_resource", "--"]
    else:
        prefix = []
    rc, screen, err = _run_in_pty(["--mock", "--swing-up", "--duration", "1.5", "--tui"], prefix=prefix,
                                  preexec_fn=_as_a_user_without_realtime_rights)
    assert rc in (0, 4) and traceback_free(err + screen), err
    seen = ANSI.sub("", screen + err)
    for warning in ("mlockall failed", "SCHED_FIFO not permitted"):
        assert seen.count(warning) == 1, f"{warning!r} shown {seen.count(warning)} times:\n{seen[-3000:]}"
    rows = [line for line in seen.splitlines() if "θ−π" in line]
    assert rows, seen[-3000:]  # the hanging pendulum is drawn from hanging, calibrating still: flat
    assert len(set(rows[0]) & BARS) <= 2, rows[0]
