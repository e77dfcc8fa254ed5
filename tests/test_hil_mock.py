"""hil_mock over a real pseudo-terminal, opened with pyserial as the daemon would open /dev/ttyUSB0.

Timing-robust on a loaded 2-core machine: assertions are about what the device guarantees (no seq is
ever skipped, the watchdog trips on device time), never about the host keeping up. The host answers
every SAMPLE with CLEAR_FAULT added whenever a fault is latched, so a host stall that trips the
20 ms watchdog does not change the outcome.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from itertools import pairwise
from pathlib import Path

import pytest
import serial

from firmware_protocol import FAULT_MASK, CommandFlags, Hello, HelloAck, Sample, StatusFlags, make_hello
from furuta_rt.controller.controller import Controller, Measurement
from furuta_rt.model.sensors import Calibration
from furuta_rt.sim.closed_loop import run_closed_loop
from hil_mock.config import build_config
from hil_mock.device import VirtualDevice
from hil_mock.host import MiniHost
from hil_mock.launch import start_mock_subprocess, stop_mock_subprocess

ENABLE = int(CommandFlags.ENABLE)
CLEAR = int(CommandFlags.CLEAR_FAULT)
WATCHDOG = int(StatusFlags.WATCHDOG_TRIPPED)


def answer(host: MiniHost, s: Sample, u: float) -> None:
    host.command(s.seq, u, ENABLE | (CLEAR if s.status & FAULT_MASK else 0))


def done_when(port: str) -> dict:
    """The issue's acceptance run: handshake; 1 s of SAMPLEs at 500 Hz without a seq gap; the plant
    responds to COMMANDs; the watchdog zeroes the actuator when COMMANDs stop."""
    with MiniHost(port) as host:
        ack = host.handshake()
        assert ack.sample_rate_hz == 500 and ack.watchdog_ms == 20
        # 1. one second of SAMPLEs, each answered with zero torque: the upright plant does not move
        got: list[Sample] = []
        while len(got) < 500:
            s = host.next_sample(timeout=2.0)
            assert s is not None, "SAMPLEs stopped"
            got.append(s)
            answer(host, s, 0.0)
        seqs = [s.seq for s in got]
        assert seqs == list(range(seqs[0], seqs[0] + 500)), "gap in the SAMPLE sequence"
        assert seqs[0] == 0
        span = got[-1].t_us - got[0].t_us
        assert span >= 499 * 2000  # device-timed at 500 Hz (more if the device overran and said so)
        assert span == 499 * 2000 or any(s.status & StatusFlags.TICK_OVERRUN for s in got)
        assert all(s.phi_count == 0 for s in got)
        # 2. +0.5 N m on the arm for 0.1 s: the arm turns positive
        push: list[Sample] = []
        while len(push) < 50:
            s = host.next_sample(timeout=2.0)
            assert s is not None
            push.append(s)
            answer(host, s, 0.5)
        assert any(s.status & StatusFlags.ENABLED for s in push)
        assert push[-1].phi_count > 10  # ≈ 25 counts: φ ≈ τ t² / 2J'
        assert [s.seq for s in push] == list(range(seqs[-1] + 1, seqs[-1] + 51))
        # 3. COMMANDs stop: the device latches WATCHDOG_TRIPPED and drops ENABLED, ≥ 20 ms (device time)
        # after the last COMMAND arrived. When that was is the host's lag (up to ~0.2 s on a loaded machine,
        # samples queue up meanwhile), so only the lower bound is checked here; the exact timing is in the
        # firmware tests. A trip left over from a host stall in step 2 is cleared by the last COMMAND first.
        last_answered = push[-1]
        after: list[Sample] = []
        clean = False
        while True:
            s = host.next_sample(timeout=2.0)
            assert s is not None
            after.append(s)
            assert len(after) < 1000, "watchdog did not trip within 2 s"
            if not s.status & WATCHDOG:
                clean = True
            elif clean:
                break
        tripped = after[-1]
        assert not tripped.status & StatusFlags.ENABLED
        assert tripped.t_us - last_answered.t_us >= 20_000
        time.sleep(0.05)
        host.poll()
        assert any(st.flags & WATCHDOG for st in host.statuses)
        return {"samples": got + push + after}


def test_done_when_subprocess(tmp_path):
    link, stats = tmp_path / "ttyMOCK0", tmp_path / "stats.json"
    proc, port = start_mock_subprocess(
        ["--rate", "500", "--initial-theta", "0", "--link", str(link), "--stats-json", str(stats)]
    )
    try:
        assert port.startswith("/dev/pts/") and link.resolve() == Path(port)
        done_when(str(link))  # a stable name, as /dev/ttyUSB0 would be
    finally:
        err = stop_mock_subprocess(proc)
    assert proc.returncode == 0 and not link.exists()
    assert "watchdog trips" in err and "late ticks" in err and "worst" in err
    st = json.loads(stats.read_text())
    assert st["watchdog_trips"] >= 1 and st["samples_sent"] >= 550 and st["handshakes"] == 1


def test_done_when_in_process():
    cfg = build_config(device={"rate_hz": 500, "initial_theta": 0.0})
    with VirtualDevice(cfg) as dev:
        done_when(dev.port)
        assert dev.firmware.output == 0.0  # the actuator itself, not only the flag
        st = dev.stats
        assert st.watchdog_trips >= 1 and st.commands_rx == 550 and st.crc_errors == 0 and st.samples_sent >= 560
    assert not dev.running


def test_a_samples_device_time_maps_onto_this_machines_clock():
    """``clock_origin_s``: in real-time pacing SAMPLE k is taken at clock_origin_s + t_k on time.perf_counter's clock
    (CLOCK_MONOTONIC, the clock a kernel trace can use), so it reaches the host after that instant, never before,
    and, read as it comes, within a few periods of it."""
    cfg = build_config(device={"rate_hz": 500, "initial_theta": 0.0})
    with VirtualDevice(cfg) as dev, MiniHost(dev.port) as host:
        host.handshake()
        arrivals: list[tuple[float, int]] = []
        while len(arrivals) < 200:
            s = host.next_sample(timeout=2.0)
            assert s is not None
            arrivals.append((time.perf_counter(), s.t_us))
            answer(host, s, 0.0)
        origin = dev.stats.clock_origin_s
    delays = sorted(arrived - (origin + t_us * 1e-6) for arrived, t_us in arrivals)
    assert delays[0] > 0.0, f"a SAMPLE arrived {-delays[0] * 1e3:.3f} ms before its tick: the origin is wrong"
    assert delays[len(delays) // 2] < 0.05, f"median delay {delays[len(delays) // 2]:.3f} s: the origin is wrong"


def lockstep_thetas(port: str, rig: object) -> list[float]:
    """The controller against a lockstep mock on ``port`` for 200 SAMPLEs; the θ it measured."""
    ctrl = Controller.from_rig(rig)
    with MiniHost(port) as host:
        ack = host.handshake()
        cal = Calibration(ack.theta_rad_per_count, ack.theta_offset_counts, ack.theta_dot_rad_s_per_count,
                          ack.phi_counts_per_rev)
        theta = []
        while len(theta) < 200:
            s = host.next_sample(timeout=5.0)
            assert s is not None
            th, thd, ph = cal.to_si(s.theta_adc, s.theta_dot_adc, s.phi_count)
            host.command(s.seq, ctrl.update(Measurement(s.seq / 500, th, thd, ph)).u, ENABLE)
            theta.append(th)
    return theta


@pytest.mark.parametrize("where", ["in-process", "subprocess"])
def test_lockstep_run_reproduces_the_closed_loop_simulation(where: str, tmp_path: Path):
    """Over the pty, pacing 'lockstep' (deterministic on any load): the controller against the mock
    sees exactly the measurements of run_closed_loop with the same seed until quantisation tells — from a device
    thread and from a hil-mock process, which waits for each COMMAND in the kernel (one poll a tick)."""
    cfg = build_config(effects=["arm_viscous.Fv=0.01"], device={"rate_hz": 500, "seed": 5, "pacing": "lockstep"})
    rig = cfg.load_rig()
    rec = run_closed_loop(rig, 0.4, effects=cfg.effects, seed=5, x0=(0.05, 0.0, 0.0, 0.0))
    if where == "in-process":
        with VirtualDevice(cfg) as dev:
            theta = lockstep_thetas(dev.port, rig)
        st = dev.stats.as_dict()
    else:
        stats = tmp_path / "stats.json"
        proc, port = start_mock_subprocess(["--effect", "arm_viscous.Fv=0.01", "--rate", "500", "--seed", "5",
                                            "--pacing", "lockstep", "--stats-json", str(stats)])
        try:
            theta = lockstep_thetas(port, rig)
        finally:
            stop_mock_subprocess(proc)
        st = json.loads(stats.read_text())
    assert st["pty_selects"] >= st["ticks"] - 2, st  # blocked for each COMMAND
    assert theta[:50] == pytest.approx(list(rec.theta[:50]), abs=1e-6)  # f32 scale from the HELLO_ACK
    assert max(abs(a - b) for a, b in zip(theta, rec.theta, strict=True)) < 5e-4


def test_wrong_schema_hash_refused_over_the_pty():
    with VirtualDevice(build_config()) as dev, MiniHost(dev.port) as host:
        hello = Hello(make_hello().protocol_version, 0xDEADBEEF, 42)
        ack = host.handshake(hello=hello, verify=False)
        assert isinstance(ack, HelloAck) and ack.schema_hash != 0xDEADBEEF
        assert host.next_sample(timeout=0.2) is None  # refused: no streaming
        assert dev.stats.handshakes_refused >= 1


def test_corrupted_bytes_are_counted_both_ways_and_no_seq_is_skipped():
    cfg = build_config(device={"rate_hz": 500, "initial_theta": 0.0},
                       fault_settings={"corrupt_rate": 0.004, "rx_corrupt_rate": 0.02})
    with VirtualDevice(cfg) as dev, MiniHost(dev.port) as host:
        host.handshake()
        got = []
        while len(got) < 400:
            s = host.next_sample(timeout=2.0)
            assert s is not None
            got.append(s)
            answer(host, s, 0.0)
        st = dev.stats
    seqs = [s.seq for s in got]
    assert seqs == sorted(set(seqs))  # in order, never duplicated
    missing = seqs[-1] - seqs[0] + 1 - len(seqs)
    assert st.tx_bytes_corrupted > 0 and host.decoder.errors > 0 and missing > 0
    assert missing <= 2 * st.tx_bytes_corrupted  # a lost SAMPLE is always explained by a corrupted byte
    assert st.rx_bytes_corrupted > 0 and st.crc_errors + st.frame_errors > 0
    assert any(s.status & StatusFlags.CRC_ERROR for s in got)


def test_scheduled_reset_restarts_seq_after_a_new_handshake():
    cfg = build_config(device={"rate_hz": 500, "initial_theta": 0.0}, faults=["reset@0.2"])
    with VirtualDevice(cfg) as dev, MiniHost(dev.port) as host:
        host.handshake()
        first = last = host.next_sample()
        while (s := host.next_sample(timeout=0.3)) is not None:
            last = s
            answer(host, s, 0.0)
        assert first is not None and last is not None and first.seq == 0
        # streaming stopped at 0.2 s of plant time: seq 99 (0.198 s) is the last, unless the device overran (it
        # skips timer periods, never seqs, and a reset due within them comes before the next tick) — then the last
        # SAMPLE is earlier by at most the periods it skipped
        span = (last.t_us - first.t_us) * 1e-6
        assert last.seq <= 99 and 0.198 - dev.stats.missed_periods * 0.002 - 1e-9 <= span <= 0.198, \
            (last, dev.stats.missed_periods)
        assert dev.stats.resets == 1 and not dev.firmware.streaming
        host.handshake()
        s = host.next_sample()
        assert s is not None and s.seq == 0 and s.t_us > last.t_us  # seq restarts, device clock does not


def test_stall_keeps_seq_and_reports_overrun():
    cfg = build_config(device={"rate_hz": 500, "initial_theta": 0.0})
    with VirtualDevice(cfg) as dev, MiniHost(dev.port) as host:
        host.handshake()
        got = []
        while len(got) < 150:
            s = host.next_sample(timeout=2.0)
            assert s is not None
            got.append(s)
            answer(host, s, 0.0)
            if len(got) == 50:
                dev.stall(0.1)
        assert dev.stats.stalls == 1
    seqs = [s.seq for s in got]
    assert seqs == list(range(seqs[0], seqs[0] + 150))
    jumps = [(b.t_us - a.t_us, b.status) for a, b in pairwise(got) if b.t_us - a.t_us >= 100_000]
    assert len(jumps) == 1 and jumps[0][1] & StatusFlags.TICK_OVERRUN


def test_host_closing_the_port_zeroes_the_actuator_and_reconnect_works():
    cfg = build_config(device={"rate_hz": 500, "initial_theta": 0.0})
    with VirtualDevice(cfg) as dev:
        host = MiniHost(dev.port)
        host.handshake()
        deadline = time.monotonic() + 5.0  # a loaded host's answers may come late (discarded): it answers until one lands
        while dev.firmware.output == 0.0 and time.monotonic() < deadline:
            s = host.newest_sample()
            assert s is not None
            answer(host, s, 0.3)
        assert dev.firmware.output > 0.0
        host.close()
        deadline = time.monotonic() + 2.0
        while dev.firmware.streaming and time.monotonic() < deadline:
            time.sleep(0.005)
        assert not dev.firmware.streaming and dev.firmware.output == 0.0 and dev.stats.hangups == 1
        with MiniHost(dev.port) as again:
            again.handshake()
            s = again.next_sample()
            assert s is not None and s.seq == 0


def test_disconnect_closes_the_device():
    with VirtualDevice(build_config(device={"rate_hz": 500})) as dev, MiniHost(dev.port) as host:
        host.handshake()
        assert host.next_sample() is not None
        dev.disconnect()
        with pytest.raises((serial.SerialException, OSError)):  # EIO or "returned no data"
            deadline = time.monotonic() + 2.0
            while time.monotonic() < deadline:
                host.poll()
        deadline = time.monotonic() + 2.0
        while dev.running and time.monotonic() < deadline:
            time.sleep(0.01)
        assert not dev.running and dev.disconnected


def test_launching_the_mock_loads_only_the_launcher_and_the_public_names_still_resolve() -> None:
    """The daemon's control process imports hil_mock only to start the mock as a child: that import must not
    pull the simulator (and its numpy/scipy) into a memory-locked real-time process."""
    probe = (
        "import sys\n"
        "from hil_mock import start_mock_subprocess, stop_mock_subprocess, MockStartError\n"
        "heavy = sorted(m for m in sys.modules if m.startswith(('hil_mock.', 'furuta_rt', 'numpy', 'scipy'))"
        " and m != 'hil_mock.launch')\n"
        "print(heavy)\n"
        "import hil_mock, hil_mock.device, hil_mock.config\n"
        "assert hil_mock.VirtualDevice is hil_mock.device.VirtualDevice\n"
        "assert hil_mock.build_config is hil_mock.config.build_config\n"
        "try:\n"
        "    hil_mock.no_such_name\n"
        "except AttributeError as err:\n"
        "    print(err)\n"
    )
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60, check=True)
    assert out.stdout.splitlines() == ["[]", "module 'hil_mock' has no attribute 'no_such_name'"]


def test_stats_json_is_written_when_the_launcher_is_gone(tmp_path):
    """A launcher killed (its pipes closed, its --exit-with-fd end gone) still leaves hil-mock's --stats-json: the
    file the user asked for is written before the summary goes to a stderr nobody reads any more."""
    import os
    import subprocess
    import sys

    stats = tmp_path / "stats.json"
    watch_r, watch_w = os.pipe()
    proc = subprocess.Popen([sys.executable, "-m", "hil_mock", "--pty", "--exit-with-fd", str(watch_r), "--rate", "500",
                             "--stats-json", str(stats)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            pass_fds=(watch_r,))
    os.close(watch_r)
    assert proc.stdout is not None and proc.stderr is not None
    assert proc.stdout.readline().strip()  # serving on its pty
    proc.stdout.close()
    proc.stderr.close()
    os.close(watch_w)  # the launcher is gone
    assert proc.wait(timeout=30) == 0
    st = json.loads(stats.read_text())
    assert st["rate_hz"] == 500 and st["handshakes"] == 0
