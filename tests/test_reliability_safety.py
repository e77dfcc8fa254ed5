"""Issue 15, items 1 and 2, at the device side: the daemon's own host path (SerialHardware + ControlLoop) over
a real pty against hil_mock's firmware (the PROTOCOL.md §6 acceptance rule), and SerialHardware writing to
a pty whose reader is slow or gone.

The device runs in lockstep pacing: each tick waits for the COMMAND answering the previous SAMPLE (up to
1 s), so "zero within one period" is asserted by tick count at the device, not by wall time, and holds on a
loaded machine.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
import time
from pathlib import Path
from typing import Any

import pytest
from test_reliability_harness import (
    DaemonProcess,
    ListSink,
    MockProcess,
    _Recorder,
    read_summary,
    start_daemon,
    traceback_free,
)

import firmware_protocol as fp
from furuta_rt.config import load_rig
from furuta_rt.control.controller import Controller
from furuta_rt.io.mcap_read import read_log
from furuta_rt.runtime.hardware import LinkLost, SerialHardware
from furuta_rt.runtime.loop import ControlLoop, LoopSettings
from furuta_rt.runtime.supervisor import Supervisor, SupervisorLimits
from hil_mock.config import build_config
from hil_mock.device import VirtualDevice
from hil_mock.ptyport import open_raw_pty

RATE = 500


class _FailingSink(ListSink):
    """A logger queue that breaks at its ``fail_at``-th put (after that tick's COMMAND went out)."""

    def __init__(self, fail_at: int) -> None:
        super().__init__()
        self.fail_at = fail_at
        self.puts = 0

    def put_nowait(self, item: Any) -> None:
        self.puts += 1
        if self.puts == self.fail_at:
            raise RuntimeError("logger queue closed")
        super().put_nowait(item)


def _output_from(rec: _Recorder, tick: int) -> list[float]:
    """The device's outputs in force from device tick ``tick`` on (an output set at tick j, after SAMPLE j,
    is recorded with the next seq j + 1; STOP between ticks j and j + 1 likewise)."""
    ticks, outs = rec.output_ticks, [u for _, _, u in rec.outputs]
    first = max(i for i, t in enumerate(ticks) if t <= tick + 1)
    return outs[first:]


@pytest.mark.parametrize("how", ["operator stop", "trip", "link loss", "exception"])
def test_the_device_output_is_zero_within_one_period_of_every_way_out(how: str) -> None:
    """Issue 15 item 1: the loop's u = 0 is accepted by a device that follows PROTOCOL.md §6 (no COMMAND
    discarded) and the actuator is zero from the device tick after the last SAMPLE the host read
    (operator stop, θ trip, exception after the tick's write), or after the SAMPLE it never got (link
    loss: the device's bytes are lost, so the host read k, the device sent k + 1)."""
    cfg = build_config(device={"rate_hz": RATE, "pacing": "lockstep", "priority": "normal", "watchdog_ms": 5000})
    rig = load_rig("thesis")
    dev = VirtualDevice(cfg)
    rec = _Recorder(dev)
    dev.start()
    hw = SerialHardware(dev.port)
    sink: ListSink = ListSink()
    gains = None
    lim = SupervisorLimits.from_config(rig.safety, RATE)
    lim = SupervisorLimits(lim.theta_limit, lim.phi_limit, lim.arm_theta, 10**9, lim.settle_ticks)
    if how == "trip":
        gains = [2.0, 0.3, 0.0, 0.0]  # too weak to hold it: it falls while driven until |θ| > 0.5 rad
    elif how == "exception":
        sink = _FailingSink(fail_at=8)  # the 8th tick batch: the put after its tick's COMMAND raises
    try:
        info = hw.handshake(RATE, 5000)
        loop = ControlLoop(hw, Controller.from_rig(rig, gains=gains), Supervisor(lim),
                           LoopSettings(rate_hz=RATE, duration=30.0, link_timeout_s=0.05, first_sample_timeout=10.0),
                           full_scale=info.full_scale, calibration=info.calibration, log=sink)
        if how == "operator stop":
            sink.put_nowait = _stop_after(loop, sink, batches=8)  # type: ignore[method-assign]
        elif how == "link loss":
            sink.put_nowait = _mute_after(dev, sink, batches=8)  # type: ignore[method-assign]
        if how == "exception":
            with pytest.raises(RuntimeError, match="logger queue closed"):
                loop.run()
        else:
            loop.run()
    finally:
        hw.close()
        dev.stop()
    r = loop.result
    expected = {"operator stop": "operator_stop", "trip": "theta_limit", "link loss": "link_loss", "exception": "error"}
    assert r.trip_reason == expected[how], (r.trip_reason, r.trip_message)
    k = loop._last_seq  # the last SAMPLE the host read
    assert any(u != 0.0 for _, _, u in rec.outputs), "the actuator was driven"
    assert all(rec.accepted), f"COMMANDs discarded: {[c for c, ok in zip(rec.commands, rec.accepted, strict=True) if not ok]}"
    first_zero_tick = k + 2 if how == "link loss" else k + 1
    assert set(_output_from(rec, first_zero_tick)) == {0.0}, (
        f"outputs from tick {first_zero_tick}: {_output_from(rec, first_zero_tick)} (host read up to {k})")
    assert rec.stops, "STOP reached the device"


def _stop_after(loop: ControlLoop, sink: ListSink, batches: int) -> Any:
    put = sink.put_nowait

    def put_nowait(item: Any) -> None:
        put(item)
        if item[0] == "ticks" and sum(1 for kind, *_ in sink.items if kind == "ticks") == batches:
            loop.request_stop("SIGINT")  # as the signal handler does, between two ticks

    return put_nowait


def _mute_after(dev: VirtualDevice, sink: ListSink, batches: int) -> Any:
    put = sink.put_nowait

    def put_nowait(item: Any) -> None:
        put(item)
        if item[0] == "ticks" and sum(1 for kind, *_ in sink.items if kind == "ticks") == batches:
            dev.mute(60.0)  # every device → host byte lost from the next tick on

    return put_nowait


# ------------------------------------------------------------------ item 2: whole frames or a loud failure
def _open_pair() -> tuple[int, SerialHardware]:
    master, port = open_raw_pty()
    hw = SerialHardware(port)
    hw.open()
    return master, hw


def test_a_slow_reader_gets_every_frame_whole() -> None:
    """The port's buffer fills because the device reads slowly: every COMMAND still arrives whole and in
    order (partial writes are completed, a full buffer is waited for), none is dropped."""
    master, hw = _open_pair()
    got: list[fp.Message] = []
    decoder = fp.StreamDecoder()
    done = threading.Event()

    def slow_reader() -> None:
        while True:
            try:
                data = os.read(master, 97)  # odd chunks: frames are cut anywhere
            except BlockingIOError:
                if done.is_set():
                    return
                time.sleep(0.002)
                continue
            except OSError:
                return
            got.extend(decoder.feed(data))
            time.sleep(0.0005)

    t = threading.Thread(target=slow_reader, daemon=True)
    t.start()
    n = 3000
    try:
        for seq in range(n):
            hw.write(seq, seq % 30000 - 15000, 1)
    finally:
        time.sleep(0.2)
        done.set()
        t.join(10)
        hw.close()
        os.close(master)
    assert decoder.errors == 0, f"{decoder.errors} torn frames reached the device"
    assert [m.seq for m in got] == list(range(n)), "every COMMAND arrived, in order"  # type: ignore[attr-defined]
    assert hw.write_errors == 0


def test_a_device_that_stops_reading_fails_loudly_and_stop_says_so() -> None:
    """Nobody reads the port: ``write`` raises LinkLost naming the port within its timeout (it never drops a
    frame silently); ``stop`` then reports that u = 0 and STOP could not be sent; once the device reads
    again, a second ``stop`` gets them out intact (a delimiter first flushes the torn frame)."""
    master, hw = _open_pair()
    try:
        with pytest.raises(LinkLost, match="not reading") as exc:
            for seq in range(1_000_000):
                hw.write(seq, 100, 1)
        assert not exc.value.gone
        err = hw.stop()
        assert err is not None and "not reading" in err
        decoder = fp.StreamDecoder()
        msgs: list[fp.Message] = []

        def drain() -> None:  # until the pty has been quiet for 0.2 s (its kernel worker moves bytes late)
            quiet = time.monotonic()
            while time.monotonic() - quiet < 0.2:
                try:
                    data = os.read(master, 65536)
                except (BlockingIOError, OSError):
                    time.sleep(0.01)
                    continue
                msgs.extend(decoder.feed(data))
                quiet = time.monotonic()

        drain()
        assert msgs and all(isinstance(m, fp.Command) for m in msgs)
        msgs.clear()
        assert hw.stop() is None
        drain()
        assert [type(m) for m in msgs] == [fp.Stop, fp.Stop], msgs
    finally:
        hw.close()
        os.close(master)


def test_the_loop_reports_a_stop_it_could_not_send() -> None:
    """A HardwareInterface whose stop() fails: the loop tells it as an ERROR event (once the zero was tried)."""
    rig = load_rig("thesis")
    from test_run_loop import SimDevice, make_loop

    class Deaf(SimDevice):
        def stop(self) -> str | None:
            self.journal.append(("stop-failed",))
            return "write to /dev/ttyX stalled: the device is not reading"

    dev = Deaf(rig)
    loop, sink = make_loop(rig, dev, duration=0.2)
    loop.run()
    errors = [e for e in sink.events() if "could not send u = 0 and STOP" in e]
    assert len(errors) == 1 and "not reading" in errors[0]


# ------------------------------------------------------------------ item 3: the mock dies with the daemon
def _alive(pid: int) -> bool:
    """Running (not gone, not a zombie waiting for a reaper)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def _semaphores(pid: int) -> set[str]:
    """Named POSIX semaphores (/dev/shm/sem.*) mapped by process ``pid``."""
    try:
        maps = Path(f"/proc/{pid}/maps").read_text()
    except OSError:
        return set()
    return {line.split()[-1] for line in maps.splitlines() if "/dev/shm/sem." in line}


def test_sigkill_of_the_daemon_alone_ends_its_mock_and_leaves_no_semaphore(tmp_path: Path) -> None:
    """Issue 15 item 3: ``furuta-rt run --mock --log`` as a user starts it; SIGKILL of the daemon process
    only (not its group). Its hil-mock child ends by itself (it was left running, at 10 % CPU), and no
    named semaphore of the run stays in /dev/shm once its processes are gone."""
    d = DaemonProcess(["--mock", "--duration", "120", "--no-tui", "--log", str(tmp_path / "run.mcap")])
    children: list[int] = []
    try:
        d.wait_for_line("→ balancing", timeout=120)
        children = d.children()
        mocks = [p for p in children if "hil_mock" in _cmdline(p)]
        assert len(mocks) == 1, [_cmdline(p) for p in children]
        sems = _semaphores(d.pid)
        assert sems, "the daemon's logger queue uses named semaphores (the check below would be empty)"
        os.kill(d.pid, signal.SIGKILL)
        d.proc.wait(30)
        end = time.monotonic() + 60.0  # a bound for a loaded machine; the mock reacts at its next tick
        while any(_alive(p) for p in children) and time.monotonic() < end:
            time.sleep(0.05)
        assert not _alive(mocks[0]), "hil-mock outlived the daemon that started it"
        assert not [p for p in children if _alive(p)], [_cmdline(p) for p in children if _alive(p)]
        leaked = sorted(s for s in sems if Path(s).exists())
        assert not leaked, f"semaphores left in /dev/shm: {leaked}"
    finally:
        d.kill_group(signal.SIGKILL)
        for p in children:
            with contextlib.suppress(ProcessLookupError):
                os.kill(p, signal.SIGKILL)


# ------------------------------------------------------------------ item 8: one mock, several hosts in a row
def test_three_hosts_in_a_row_against_one_mock_each_balance(tmp_path: Path) -> None:
    """Issue 15 item 8: against one ``hil-mock --pty``, three ``furuta-rt run --port`` one after the other.
    The mock kept the pendulum the previous host dropped (after its STOP it fell and hung at θ = π, θ's
    ADC at its rail with ADC_OVERRANGE latched), so every host after the first idled, never armed and
    ended "never balanced". Each new session must start from the rig's initial state, as a fresh mock's."""
    mock = MockProcess(tmp_path, [])
    runs = []
    try:
        for i in range(3):
            d = tmp_path / f"run{i}"
            d.mkdir()
            daemon = start_daemon(d, mock.port, duration=2.0)
            rc = daemon.wait(timeout=120)
            runs.append((rc, daemon, d))
            time.sleep(1.0)  # unactuated after STOP: the pendulum falls meanwhile (≈ 0.5 s)
    finally:
        rec = mock.stop()
    for i, (rc, daemon, d) in enumerate(runs):
        assert traceback_free(daemon.stderr + daemon.stdout), daemon.stderr
        s = read_summary(d)
        assert rc == 0 and s["end"] == "duration", f"host {i + 1}: exit {rc}, {s['end']} {s['trip_message']}"
        log = read_log(d / "run.mcap")
        assert log.ticks["seq"][0] < 10, f"host {i + 1}: a fresh session (seq from 0)"
        assert abs(log.ticks["theta"][0] - 0.05) < 0.01, f"host {i + 1} found θ = {log.ticks['theta'][0]:.3f} rad"
        assert (log.ticks["state"] == "balancing").sum() > 0.8 * log.n_ticks, f"host {i + 1} did not balance"
    assert sum(1 for _, _, what in rec.events if what == "hello") >= 3
    rec.assert_ends_safe()
