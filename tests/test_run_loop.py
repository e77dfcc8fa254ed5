"""The control loop (read → update → write) against an in-process simulated device: what it sends, what it
logs, how it trips, and the timing helpers. The HIL tests (test_run_hil.py) run the real daemon."""

from __future__ import annotations

import contextlib
import math
import os
import queue
import select
import signal
import threading
import time
from collections import deque
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import firmware_protocol as fp
from firmware_protocol import COMMAND_FULL_SCALE, CommandFlags, Sample, StatusFlags, counts_to_actuator
from furuta_rt.cli import main as cli_main
from furuta_rt.config import RigConfig, load_rig
from furuta_rt.controller.controller import Controller, Measurement
from furuta_rt.errors import UserError
from furuta_rt.model.rig import RigModel
from furuta_rt.runtime.hardware import DeviceInfo, HardwareInterface, SerialHardware, check_usb_latency
from furuta_rt.runtime.loop import TICK_RECORD, ControlLoop, LoopResult, LoopSettings
from furuta_rt.runtime.summary import format_summary, summary_dict
from furuta_rt.runtime.supervisor import STATE_NAMES, Supervisor, SupervisorLimits
from furuta_rt.runtime.timing import DeviceClock, Histogram, RunningStats
from furuta_rt.sim.simulator import Simulator

F = {name: i for i, name in enumerate(TICK_RECORD)}
ENABLE = int(CommandFlags.ENABLE)
CLEAR = int(CommandFlags.CLEAR_FAULT)
RATE = 500


class SimDevice(HardwareInterface):
    """The core Simulator behind the HardwareInterface, with the firmware's tick order: at tick k the
    newest accepted COMMAND (answering ≤ k−1) sets the output, SAMPLE k is taken, the plant advances.
    COMMANDs are accepted by PROTOCOL.md §6 through firmware_protocol.command_accepted (the rule
    hil_mock's firmware uses); STOP zeroes the output at once. ``stop()`` sends what
    SerialHardware.stop sends (``zero_answer``, then STOP). ``bursts[seq] = n`` delivers n samples at
    once (a host stall); ``silent_after`` ends the stream; ``device_skips[seq] = k``: the device's tick of SAMPLE
    seq is k periods late (hil_mock's and an MCU timer's overrun: the plant runs k periods with the output held,
    the clock skips them, seq does not, TICK_OVERRUN is set); SAMPLEs in ``lost`` are sent but never arrive."""

    def __init__(self, rig: RigConfig, *, x0: tuple[float, ...] = (0.05, 0.0, 0.0, 0.0), bursts: dict[int, int] | None = None,
                 silent_after: int | None = None, status: dict[int, int] | None = None, on_read: Any = None,
                 device_skips: dict[int, int] | None = None, lost: set[int] | None = None) -> None:
        self.sim = Simulator(RigModel.from_config(rig), rig.control.rate_hz, seed=1, x0=x0)  # type: ignore[arg-type]
        self.full_scale = rig.actuator.limit
        self.period_us = round(1e6 / rig.control.rate_hz)
        self.bursts = bursts or {}
        self.silent_after = silent_after
        self.status = status or {}
        self.on_read = on_read
        self.device_skips = device_skips or {}
        self.lost = lost or set()
        self.seq = 0
        self.skipped = 0  # timer periods the device skipped so far
        self.cmd: tuple[int, int, int] | None = None  # newest accepted COMMAND
        self.stopped = False
        self.written: int | None = None  # host side: seq of the last COMMAND written
        self.outputs: list[tuple[int, float]] = []  # (tick, output applied at that tick)
        self.queue: deque[Sample] = deque()
        self.journal: list[tuple] = []  # ("write", seq, counts, flags, accepted) | ("stop",) | what the sinks add

    def handshake(self, rate_hz: int, watchdog_ms: int) -> Any:  # pragma: no cover - not used by the loop
        raise NotImplementedError

    @property
    def next_output(self) -> float:
        """The output the device drives from its next tick on (STOP: zero at once)."""
        cmd = self.cmd
        if self.stopped or cmd is None or not cmd[2] & ENABLE:
            return 0.0
        return counts_to_actuator(cmd[1], self.full_scale)

    def _tick(self) -> Sample:
        u = self.next_output
        status = self.status.get(self.seq, 0)
        late = self.device_skips.get(self.seq, 0)
        if late:
            self.sim.set_command(u)
            for _ in range(late):
                self.sim.advance()
            self.skipped += late
            status |= int(StatusFlags.TICK_OVERRUN)
        self.outputs.append((self.seq, u))
        raw = self.sim.sample()
        s = Sample(self.seq, ((self.seq + self.skipped) * self.period_us) & 0xFFFFFFFF, raw.theta_adc, raw.theta_dot_adc,
                   raw.phi_count, status)
        self.sim.set_command(u)
        self.sim.advance()
        self.seq += 1
        return s

    def read(self, timeout: float) -> Sample | None:
        if self.on_read is not None:
            self.on_read(self)
        if not self.queue:
            if self.stopped or (self.silent_after is not None and self.seq >= self.silent_after):
                return None
            for _ in range(self.bursts.get(self.seq, 1)):
                s = self._tick()
                while s.seq in self.lost:  # sent, never arrived
                    s = self._tick()
                self.queue.append(s)
            self.arrival_ns = time.perf_counter_ns()
        return self.queue.popleft()

    @property
    def pending(self) -> int:
        return len(self.queue)

    def write(self, seq: int, counts: int, flags: int) -> None:
        last_sent = self.seq - 1 if self.seq else None
        ok = not self.stopped and fp.command_accepted(seq, last_sent, None if self.cmd is None else self.cmd[0])
        self.journal.append(("write", seq, counts, flags, ok))
        self.written = seq
        if ok:
            self.cmd = (seq, counts, flags)

    def stop(self) -> str | None:
        if self.stopped:
            return None
        newest = self.queue[-1].seq if self.queue else (self.seq - 1 if self.seq else None)
        seq = fp.zero_answer(newest, self.written)
        if seq is not None:
            self.write(seq, 0, 0)
        self.journal.append(("stop",))
        self.stopped = True
        return None

    def close(self) -> None:
        pass

    @property
    def writes(self) -> list[tuple]:
        return [j for j in self.journal if j[0] == "write"]

    @property
    def ops(self) -> list[tuple]:
        """What reached the device: writes and STOP, in order."""
        return [j for j in self.journal if j[0] in ("write", "stop")]


class JournalSink:
    """Logger/dashboard queue stand-in that writes into the device's journal (to check the order of
    commands and logging), with the device's ``next_output`` at that moment; ``full_every`` makes
    every n-th put raise queue.Full, ``fail_at`` makes that put raise RuntimeError (a broken queue)."""

    def __init__(self, dev: SimDevice, full_every: int = 0, fail_at: int = 0) -> None:
        self.dev = dev
        self.journal = dev.journal
        self.full_every = full_every
        self.fail_at = fail_at
        self.puts = 0

    def put_nowait(self, item: Any) -> None:
        self.puts += 1
        if self.full_every and self.puts % self.full_every == 0:
            raise queue.Full
        if self.puts == self.fail_at:
            raise RuntimeError("logger queue closed")
        self.journal.append(("log", item, self.dev.next_output))

    def items(self) -> list[tuple]:
        return [e[1] for e in self.journal if e[0] == "log"]

    def ticks(self) -> list[tuple]:
        return [rec for item in self.items() if item[0] == "ticks" for rec in item[1]]

    def events(self) -> list[str]:
        return [item[1][2] for item in self.items() if item[0] == "event"]


def make_loop(rig: RigConfig, dev: SimDevice, *, duration: float | None = 2.0, gains: list[float] | None = None,
              max_overruns: int = 5, full_every: int = 0, fail_at: int = 0,
              controller: Controller | None = None, stale_age_periods: int = 1_000_000) -> tuple[ControlLoop, JournalSink]:
    """The loop against ``dev``. The aged-SAMPLE gate measures wall-clock time the host held a SAMPLE, which a loaded
    machine can push past any limit at any tick: it is off (``stale_age_periods`` huge) except in the test of the gate,
    so the other tests' counts of skipped periods and overruns are the device's alone."""
    limits = SupervisorLimits.from_config(rig.safety, RATE)
    limits = SupervisorLimits(limits.theta_limit, limits.phi_limit, limits.arm_theta, max_overruns, limits.settle_ticks)
    sink = JournalSink(dev, full_every, fail_at)
    loop = ControlLoop(
        dev, controller or Controller.from_rig(rig, gains=gains), Supervisor(limits),
        LoopSettings(rate_hz=RATE, duration=duration, link_timeout_s=0.004, stale_age_periods=stale_age_periods),
        full_scale=rig.actuator.limit, calibration=RigModel.from_config(rig).calibration, log=sink,
        on_event=lambda level, msg: dev.journal.append(("print", level, msg, dev.next_output)),
    )
    return loop, sink


@pytest.fixture
def rig() -> RigConfig:
    return load_rig("thesis")


def _col(ticks: list[tuple], name: str) -> np.ndarray:
    return np.array([rec[F[name]] for rec in ticks])


def test_balances_logs_every_tick_and_replays_bit_identically(rig: RigConfig) -> None:
    dev = SimDevice(rig)
    loop, sink = make_loop(rig, dev, duration=3.0)
    r = loop.run()
    ticks = sink.ticks()
    assert r.end == "duration" and r.ticks == 3 * RATE == len(ticks)
    assert _col(ticks, "seq").tolist() == list(range(3 * RATE)), "one record per device tick, in order"
    states = [STATE_NAMES[s] for s in _col(ticks, "state")]
    assert states[0] == "armed" and states[-1] == "balancing" and "tripped" not in states
    assert _col(ticks, "reset").tolist() == [True] + [False] * (len(ticks) - 1), "reset once, at arming"
    theta = _col(ticks, "theta")
    assert np.abs(theta[-RATE:]).max() < 0.01, "balanced in the last second"
    # commands: one per tick, ENABLE exactly while balancing, counts = the logged u
    writes = dev.writes
    assert [w[1] for w in writes] == list(range(3 * RATE)) and all(w[4] for w in writes), "all accepted (§6)"
    for rec, (_, _, counts, flags, _) in zip(ticks, writes, strict=True):
        balancing = STATE_NAMES[rec[F["state"]]] == "balancing"
        assert bool(flags & ENABLE) == balancing
        expected = round(rec[F["u"]] / rig.actuator.limit * COMMAND_FULL_SCALE)
        assert counts == (expected if balancing else 0) and (balancing or rec[F["u"]] == 0.0)
    # the last SAMPLE got its ENABLE COMMAND: a zero answering it again would be discarded (§6); STOP zeroes
    assert dev.ops[-1] == ("stop",) and dev.next_output == 0.0, "ends with STOP, the output zero"
    # the replay rule of furuta_rt.io.log_schema reproduces u and φ̂̇ bit for bit
    ctrl = Controller.from_rig(rig)
    for rec in ticks:
        m = Measurement(rec[F["t"]], rec[F["theta"]], rec[F["theta_dot"]], rec[F["phi"]])
        if rec[F["reset"]]:
            ctrl.reset(m.phi)
        if STATE_NAMES[rec[F["state"]]] == "balancing":
            out = ctrl.update(m)
            assert (out.u, out.u_lin, out.u_comp, out.phi_dot_hat) == (
                rec[F["u"]], rec[F["u_lin"]], rec[F["u_comp"]], rec[F["phi_dot_hat"]])
        else:
            assert ctrl.hold(m) == rec[F["phi_dot_hat"]]
    # accounting
    assert r.balancing_ticks == states.count("balancing") and r.overruns == r.skipped_periods == r.seq_gaps == 0
    assert r.theta.n == r.balancing_ticks - RATE and r.theta.std < 0.005
    assert r.update_us.count == r.ticks and r.latency_us.count == r.ticks


def _output_when_told(dev: SimDevice, needle: str) -> float:
    """The device's output from its next tick on, when the event containing ``needle`` was first logged or
    printed (the actuator must be zero by then: PROTOCOL.md §6 acceptance, or STOP)."""
    for e in dev.journal:
        if e[0] == "print" and needle in e[2]:
            return e[3]
        if e[0] == "log" and e[1][0] == "event" and needle in e[1][1][2]:
            return e[2]
    raise AssertionError(f"no event with {needle!r}")


@pytest.mark.parametrize("how", ["operator stop", "theta trip", "link loss", "exception before the write",
                                 "exception after the write"])
def test_every_way_out_zeroes_the_device_before_it_is_told(rig: RigConfig, how: str) -> None:
    """Issue 15 item 1, against a device that follows PROTOCOL.md §6 (firmware_protocol.command_accepted):
    when the loop first logs or prints why it stops, the device already drives zero from its next tick on
    (within one period of the SAMPLE that showed the fault), no COMMAND was discarded, and the device's
    output stays zero to the end."""
    kw: dict[str, Any] = {}
    sim_kw: dict[str, Any] = {}
    if how == "operator stop":
        sim_kw["on_read"] = lambda d: d.seq == 300 and not d.queue and os.kill(os.getpid(), signal.SIGINT)
        needle = "operator stop"
    elif how == "theta trip":
        kw["gains"] = [2.0, 0.3, 0.0, 0.0]  # too weak to hold it: it falls while driven, |θ| > 0.5 rad trips
        needle = "→ tripped"
    elif how == "link loss":
        sim_kw["silent_after"] = 400
        needle = "link loss"
    elif how == "exception after the write":
        kw["fail_at"] = 8  # the 8th logger put (a tick batch, after that tick's COMMAND) raises
        needle = "RuntimeError"
    else:
        kw["controller"] = broken_controller(rig)
        needle = "ZeroDivisionError"
    dev = SimDevice(rig, **sim_kw)
    loop, _ = make_loop(rig, dev, duration=10.0, **kw)
    if how.startswith("exception"):
        with pytest.raises((RuntimeError, ZeroDivisionError)):
            loop.run()
    else:
        loop.run()
    assert any(u != 0.0 for _, u in dev.outputs), "the actuator was driven before"
    assert _output_when_told(dev, needle) == 0.0, "the device still drives the actuator when the stop is told"
    assert all(w[4] for w in dev.writes), f"COMMANDs discarded by §6: {[w for w in dev.writes if not w[4]]}"
    assert dev.ops[-1] == ("stop",) and dev.next_output == 0.0


def test_theta_trip_writes_zero_before_logging_or_printing(rig: RigConfig) -> None:
    """With zero gains the pendulum falls: |θ| > 0.5 rad trips; the zero command precedes the event."""
    dev = SimDevice(rig)
    loop, sink = make_loop(rig, dev, duration=10.0, gains=[0.0, 0.0, 0.0, 0.0])
    r = loop.run()
    assert r.end == "trip" and r.trip_reason == "theta_limit"
    trip_seq = sink.ticks()[-1][F["seq"]]
    j = dev.journal
    i_zero = j.index(("write", trip_seq, 0, 0, True))
    i_event = next(i for i, e in enumerate(j) if e[0] == "log" and e[1][0] == "event" and "→ tripped" in e[1][1][2])
    i_print = next(i for i, e in enumerate(j) if e[0] == "print" and "→ tripped" in e[2])
    assert i_zero < i_event and i_zero < i_print
    last = sink.ticks()[-1]
    assert STATE_NAMES[last[F["state"]]] == "tripped" and last[F["u"]] == 0.0 and abs(last[F["theta"]]) > 0.5
    assert not [w for w in dev.writes if w[1] >= trip_seq and w[3] & ENABLE]
    assert dev.ops[-1] == ("stop",)


def test_link_loss_trips_with_zero(rig: RigConfig) -> None:
    dev = SimDevice(rig, silent_after=400)
    loop, sink = make_loop(rig, dev, duration=10.0)
    r = loop.run()
    assert r.end == "trip" and r.trip_reason == "link_loss" and r.ticks == 400
    assert dev.ops[-1] == ("stop",) and all(w[4] for w in dev.writes)
    assert any("link loss: no SAMPLE" in e for e in sink.events())
    assert _output_when_told(dev, "link loss") == 0.0


def test_sigint_stops_with_zero_and_restores_the_handler(rig: RigConfig) -> None:
    """The loop's own handler takes a SIGINT while it runs (u = 0 first) and the handler it found is back after.
    The handler before the run is the test's own: the worker process's may be anything an earlier test left."""

    def before(_signum: int, _frame: object) -> None:
        raise AssertionError("SIGINT reached the handler from before the run, not the loop's")

    def interrupt(dev: SimDevice) -> None:
        if dev.seq == 300 and not dev.queue:
            os.kill(os.getpid(), signal.SIGINT)

    previous = signal.signal(signal.SIGINT, before)
    try:
        dev = SimDevice(rig, on_read=interrupt)
        loop, sink = make_loop(rig, dev, duration=10.0)
        r = loop.run()
        assert r.end == "operator_stop" and r.trip_reason == "operator_stop"
        assert dev.writes[-1] == ("write", 300, 0, 0, True) and dev.ops[-1] == ("stop",)
        assert any("operator stop (SIGINT)" in e for e in sink.events())
        assert _output_when_told(dev, "operator stop") == 0.0
        assert signal.getsignal(signal.SIGINT) is before
    finally:
        signal.signal(signal.SIGINT, previous)


def test_ticks_missing_from_a_run_are_the_devices_skipped_periods_and_lost_samples(rig: RigConfig) -> None:
    """--duration is device time, so a run logs fewer ticks than duration × rate by the periods that had no SAMPLE at
    the host: SAMPLEs lost on the link (seq gaps) and periods the device itself skipped when its tick overran (its
    clock moves on, seq does not). A host stall skips periods too, but its stale SAMPLEs are ticks, logged: they are
    no part of the missing ones, and a device that overruns while the host keeps up leaves ticks missing with no
    host overrun at all."""
    dev = SimDevice(rig, bursts={200: 3}, device_skips={300: 3, 600: 1}, lost={450, 451})
    loop, sink = make_loop(rig, dev, duration=2.0)
    r = loop.run()
    assert r.end == "duration" and len(sink.ticks()) == r.ticks
    missing = 2 * RATE - r.ticks
    assert (r.overruns, r.skipped_periods) == (1, 2)  # the burst: two stale SAMPLEs, logged, then one overrun
    assert (r.device_overruns, r.device_skipped_periods, r.seq_gaps) == (2, 4, 2)
    assert missing == r.device_skipped_periods + r.seq_gaps == 6 > r.overruns + r.skipped_periods
    # every period the run spans is a logged tick, a lost SAMPLE or a period the device skipped (a device skipping past
    # the run's end spans more: then fewer ticks are missing than it skipped)
    assert r.ticks + r.seq_gaps + r.device_skipped_periods == round(r.device_span_s * RATE) + 1 == 2 * RATE
    s = summary_dict(r, rate_hz=RATE, mode="none", rig=rig.name, log_path=None, warnings=[])
    assert (s["device_skipped_periods"], s["device_overruns"]) == (4, 2)
    assert "own overruns 2 (4 periods skipped)" in format_summary(r, rate_hz=RATE, mode="none", rig=rig.name, log_path=None)


def test_the_summary_reports_the_control_processs_cpu_a_tick(rig: RigConfig) -> None:
    """CPU time, not wall time: the loop thread's own (≤ the run's wall time, however loaded the machine) and the
    whole process's, per tick, in the JSON and the printed summary."""
    dev = SimDevice(rig)
    loop, _ = make_loop(rig, dev, duration=1.0)
    start = time.perf_counter()
    r = loop.run()
    wall = time.perf_counter() - start
    assert r.ticks == RATE and 0 < r.loop_cpu_s <= wall and r.process_cpu_s >= r.loop_cpu_s - 1e-3
    cpu = summary_dict(r, rate_hz=RATE, mode="none", rig=rig.name, log_path=None, warnings=[])["control_cpu_us_per_tick"]
    assert cpu == {"loop": pytest.approx(r.loop_cpu_s / RATE * 1e6), "process": pytest.approx(r.process_cpu_s / RATE * 1e6)}
    text = format_summary(r, rate_hz=RATE, mode="none", rig=rig.name, log_path=None)
    assert f"control CPU a tick: {cpu['loop']:.0f} µs in the loop ({cpu['loop'] * RATE * 1e-4:.1f} % of the period)" in text


def test_stale_samples_skip_whole_periods_without_commands(rig: RigConfig) -> None:
    """A host stall delivers 4 samples at once: all four are ticks (logged, observer stepped), the three
    stale ones get no COMMAND, and it counts as one overrun of 3 skipped periods."""
    dev = SimDevice(rig, bursts={400: 4})
    loop, sink = make_loop(rig, dev, duration=2.0)
    r = loop.run()
    assert r.end == "duration" and r.ticks == 2 * RATE and len(sink.ticks()) == r.ticks
    answered = [w[1] for w in dev.writes]
    assert {400, 401, 402}.isdisjoint(answered) and 403 in answered
    assert r.overruns == 1 and r.skipped_periods == 3
    timing = {rec[F["seq"]]: rec for rec in sink.ticks()}
    assert [timing[s][F["latency_us"]] for s in (400, 401, 402)] == [-1.0] * 3 and timing[403][F["latency_us"]] > 0
    assert timing[403][F["overruns"]] == 1 and timing[399][F["overruns"]] == 0


class _StallingController(Controller):
    """The process stopped (SIGSTOP, starved) between read and write: ``update`` of one tick takes 30 ms."""

    stall_at_t = 0.8

    def update(self, m: Measurement) -> Any:
        if abs(m.t - self.stall_at_t) < 1e-6:
            time.sleep(0.030)
        return super().update(m)


def test_a_sample_aged_in_a_stall_at_the_write_gets_no_enable(rig: RigConfig) -> None:
    """A stall after the read (the host stall test's SIGSTOP landing between read and write): the torque computed
    from a SAMPLE the host held 30 ms (limit LoopSettings.stale_age_periods = 5 periods) is not sent; the device ticked on
    meanwhile (its 15 SAMPLEs arrive together, 14 of them stale), and the run of skipped periods counts as one overrun;
    balancing goes on. A loaded machine may starve the loop past the age limit elsewhere too: those periods are skipped
    by the same rule, so the assertions name the stall's 15 periods and check the counts against the ticks' records."""
    stalled = round(_StallingController.stall_at_t * RATE)
    dev = SimDevice(rig, bursts={stalled + 1: 15})
    ctrl = Controller.from_rig(rig)
    ctrl.__class__ = _StallingController  # the rig's controller, with the stall
    loop, sink = make_loop(rig, dev, duration=2.0, controller=ctrl, stale_age_periods=LoopSettings.stale_age_periods)
    r = loop.run()
    answered = {w[1] for w in dev.writes}
    assert set(range(stalled, stalled + 15)).isdisjoint(answered), "no COMMAND from the SAMPLE that aged in the stall"
    timing = {rec[F["seq"]]: rec for rec in sink.ticks()}
    skipped = {seq for seq, rec in timing.items() if rec[F["latency_us"]] == -1.0}
    assert set(range(stalled, stalled + 15)) <= skipped and r.skipped_periods == len(skipped)
    assert not skipped & answered and r.end == "duration"
    assert timing[stalled][F["update_us"]] > 30_000
    before = max(seq for seq in answered if seq < stalled)  # the last COMMAND before the stall, the first after it
    after = min(seq for seq in answered if seq >= stalled + 15)
    assert set(range(before + 1, after)) <= skipped  # one run of skipped periods ...
    assert timing[after][F["overruns"]] - timing[before][F["overruns"]] == 1  # ... is one overrun
    assert r.overruns >= 1


def test_repeated_overruns_trip(rig: RigConfig) -> None:
    bursts = {400 + 3 * k: 3 for k in range(6)}  # a stall before each of six commanded ticks in a row
    dev = SimDevice(rig, bursts=bursts)
    loop, _ = make_loop(rig, dev, duration=3.0, max_overruns=5)
    r = loop.run()
    assert r.end == "trip" and r.trip_reason == "overruns" and r.overruns == 5
    assert dev.writes[-1][2:] == (0, 0, True) and dev.ops[-1] == ("stop",)


def test_seq_going_back_trips_with_zero(rig: RigConfig) -> None:
    """The device restarts its seq without a handshake (a reboot the host did not see): trip at once."""
    def restart(dev: SimDevice) -> None:
        if dev.seq == 300 and not dev.queue:
            dev.seq = 0

    dev = SimDevice(rig, on_read=restart)
    loop, _ = make_loop(rig, dev, duration=10.0)
    r = loop.run()
    assert r.end == "trip" and r.trip_reason == "sequence" and "from 299 to 0" in r.trip_message
    assert dev.ops[-1] == ("stop",) and not [w for w in dev.writes[300:] if w[3] & ENABLE]
    assert _output_when_told(dev, "restarted without a handshake") == 0.0


def test_latched_device_fault_is_cleared_while_idle_before_arming(rig: RigConfig) -> None:
    wd = int(StatusFlags.WATCHDOG_TRIPPED)
    dev = SimDevice(rig, status={0: wd, 1: wd, 2: wd})
    loop, sink = make_loop(rig, dev, duration=0.1)
    loop.run()
    states = [STATE_NAMES[s] for s in _col(sink.ticks(), "state")]
    assert states[:4] == ["idle", "idle", "idle", "armed"]
    assert [w[3] for w in dev.writes[:3]] == [CLEAR] * 3 and dev.writes[3][3] == 0


def test_a_full_log_queue_drops_and_counts_never_blocks(rig: RigConfig) -> None:
    dev = SimDevice(rig)
    loop, sink = make_loop(rig, dev, duration=2.0, full_every=3)
    r = loop.run()
    assert r.end == "duration" and r.dropped_log_messages > 0
    dropped_ticks, dropped_events = r.ticks - len(sink.ticks()), len(r.events) - len(sink.events())
    assert dropped_ticks > 0 and dropped_ticks + dropped_events == r.dropped_log_messages
    counter = _col(sink.ticks(), "dropped")  # cumulative as of each record: later drops are not in it
    assert (np.diff(counter) >= 0).all() and 0 < counter[-1] <= r.dropped_log_messages


def broken_controller(rig: RigConfig) -> Controller:
    """The rig's controller, whose update raises ZeroDivisionError from t = 0.5 s on."""

    class Broken(Controller):
        def update(self, m: Measurement) -> Any:
            if m.t > 0.5:
                raise ZeroDivisionError("boom")
            return super().update(m)

    base = Controller.from_rig(rig)
    return Broken(base.gains, base.observer, base.compensator, base.u_limit)


def test_an_exception_in_the_update_sends_zero_and_propagates(rig: RigConfig) -> None:
    ctrl = broken_controller(rig)
    dev = SimDevice(rig)
    loop, _ = make_loop(rig, dev, duration=2.0, controller=ctrl)
    with pytest.raises(ZeroDivisionError):
        loop.run()
    assert dev.writes[-1][2:] == (0, 0, True) and dev.ops[-1] == ("stop",)
    assert loop.result.end == "error" and loop.sup.reason == "error"
    assert _output_when_told(dev, "ZeroDivisionError") == 0.0


# ------------------------------------------------------------------ timing helpers
def test_device_clock_unwraps_and_maps_to_the_host() -> None:
    clk = DeviceClock()
    raw = [0xFFFF_FF00, 0xFFFF_FFF0, 0x10, 0x2000]
    assert [clk.unwrap(t) for t in raw] == [0xFFFF_FF00, 0xFFFF_FFF0, 0x1_0000_0010, 0x1_0000_2000]
    clk = DeviceClock(drift_ppm=0.0)
    # host receive = device time + 1 ms transport, with jitter; the fastest sample sets the offset
    assert clk.observe(0, 1_200_000) == 1_200_000
    assert clk.observe(2000, 3_000_000) == 3_000_000
    assert clk.observe(4000, 5_500_000) == 5_000_000


def test_histogram_percentiles_and_running_stats() -> None:
    h = Histogram(size=1000)
    for v in range(1, 101):
        h.add(v - 0.5)
    h.add(5000.0)  # overflow: the max stays exact
    assert h.percentile(0.5) == 51 and h.percentile(0.99) == 100 and h.max == 5000.0 and h.min == 0.5
    assert math.isnan(Histogram().percentile(0.5))
    # values appended to ``pending`` and folded in batches (the loop's way) bin as one ``add`` each: percentiles read
    # off a sorted copy, out-of-range values in the first and the last bin
    rng = np.random.default_rng(1)
    values = [float(v) for v in np.concatenate([rng.gamma(2.0, 40.0, 5000), [-3.0, 0.0, 999.99, 1000.0, 1e6]])]
    rng.shuffle(values)
    batched = Histogram(size=1000)
    for k, v in enumerate(values):
        batched.pending.append(v)
        if k % 97 == 0:
            batched.fold()
    clamped = sorted(min(max(int(v), 0), 1000) for v in values)
    for q in (0.01, 0.5, 0.9, 0.99, 0.999, 1.0):
        i = clamped[math.ceil(q * len(values)) - 1]  # the bin holding the q-th value
        assert batched.percentile(q) == (min(i + 1.0, max(values)) if i < 1000 else max(values)), q
    assert (batched.count, batched.max, batched.min) == (len(values), 1e6, -3.0) and batched.pending == []
    assert batched.mean == pytest.approx(float(np.mean(values)), rel=1e-12) and sorted(batched.bins) == sorted(set(clamped))
    rs = RunningStats()
    data = np.random.default_rng(0).normal(1.0, 2.0, 1000)
    for x in data:
        rs.add(float(x))
    assert rs.std == pytest.approx(float(np.std(data)), rel=1e-12) and rs.mean == pytest.approx(float(np.mean(data)))


# ------------------------------------------------------------------ start-up checks
def test_usb_latency_timer_above_1ms_is_reported_with_the_fix(tmp_path: Path) -> None:
    sysfs = tmp_path / "usb-serial"
    (sysfs / "ttyUSB3").mkdir(parents=True)
    (sysfs / "ttyUSB3" / "latency_timer").write_text("16\n")
    dev = tmp_path / "ttyUSB3"
    dev.write_text("")
    link = tmp_path / "usb-FTDI_FT232R-if00-port0"
    link.symlink_to(dev)
    msg = check_usb_latency(str(link), None, sysfs=str(sysfs))
    assert msg is not None and "16 ms" in msg and f"echo 1 | sudo tee {sysfs}/ttyUSB3/latency_timer" in msg
    (sysfs / "ttyUSB3" / "latency_timer").write_text("1\n")
    assert check_usb_latency(str(link), None, sysfs=str(sysfs)) is None
    assert check_usb_latency("/dev/ttyACM0", None, sysfs=str(sysfs)) is None


class ScriptedDaq:
    """A device on a raw pty that answers HELLO with ``ack`` (fields overridden) and CONFIG with ``status``;
    ``slow_first_hello``: it answers the first HELLO 150 ms late (the host has retried meanwhile) and streams two
    SAMPLEs, then the retried HELLO restarts the session (PROTOCOL.md §5) and it streams again from seq 0 at 50 ms."""

    def __init__(self, ack: dict[str, Any], status_flags: int = 0, status_rate: int | None = None,
                 slow_first_hello: bool = False) -> None:
        from hil_mock.ptyport import open_raw_pty

        self.fd, self.port = open_raw_pty()
        self.ack, self.status_flags, self.status_rate = ack, status_flags, status_rate
        self.slow_first_hello = slow_first_hello
        self.received: list[Any] = []
        self._decoder = fp.StreamDecoder()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        decoder = self._decoder
        while not self._stop.is_set():
            if not select.select([self.fd], [], [], 0.01)[0]:
                continue
            try:
                data = os.read(self.fd, 4096)
            except OSError:  # EIO until the host opens the port, and after it closes it
                time.sleep(0.01)
                continue
            for msg in decoder.feed(data):
                self.received.append(msg)
                if isinstance(msg, fp.Hello):
                    base = dict(protocol_version=fp.PROTOCOL_VERSION, schema_hash=fp.SCHEMA_HASH, nonce=msg.nonce,
                                device_id=7, fw_major=1, fw_minor=2, fw_patch=3, sample_rate_hz=500, watchdog_ms=20,
                                theta_rad_per_count=1e-4, theta_offset_counts=0, theta_dot_rad_s_per_count=1e-3,
                                theta_dot_offset_counts=0, phi_counts_per_rev=4096, actuator_full_scale=2.0,
                                actuator_kind=0, reset_cause=fp.ResetCause.POWER_ON)
                    hellos = sum(isinstance(m, fp.Hello) for m in self.received)
                    if self.slow_first_hello and hellos == 1:
                        time.sleep(0.15)
                    os.write(self.fd, fp.encode(fp.HelloAck(**{**base, **self.ack})))
                    if self.slow_first_hello:
                        time.sleep(0.01)
                        t0_us = 0 if hellos == 1 else 50_000
                        for seq in range(2 if hellos == 1 else 1):
                            os.write(self.fd, fp.encode(fp.Sample(seq, t0_us + 2000 * seq, 0, 0, 0, 0)))
                elif isinstance(msg, fp.Config):
                    rate = msg.rate_hz if self.status_rate is None else self.status_rate
                    os.write(self.fd, fp.encode(fp.Status(self.status_flags, rate, msg.watchdog_ms, 0, 0, 1, 0, 0, 0)))

    def close(self) -> None:
        """Stop serving, then read what the host wrote last (its STOP) that the serving thread had not read yet."""
        self._stop.set()
        self._thread.join(5)
        while select.select([self.fd], [], [], 0)[0]:
            try:
                data = os.read(self.fd, 4096)
            except OSError:  # EIO: the host closed its end and nothing is left
                break
            if not data:
                break
            self.received.extend(self._decoder.feed(data))
        os.close(self.fd)


@pytest.mark.parametrize(
    ("ack", "status_flags", "needle"),
    [
        ({"schema_hash": fp.SCHEMA_HASH ^ 1}, 0, "schema hash mismatch"),
        ({"protocol_version": fp.PROTOCOL_VERSION + 1}, 0, "protocol version mismatch"),
        ({"sample_rate_hz": 1000}, int(fp.StatusFlags.CONFIG_REJECTED), "rejected rate 500 Hz"),
    ],
)
def test_handshake_refuses_a_mismatched_device(ack: dict[str, Any], status_flags: int, needle: str) -> None:
    daq = ScriptedDaq(ack, status_flags)
    hw = SerialHardware(daq.port)
    try:
        with pytest.raises(UserError, match=needle):
            hw.handshake(500, 20)
    finally:
        hw.close()
        daq.close()


def _handshake_with(daq: ScriptedDaq, rate_hz: int, watchdog_ms: int) -> DeviceInfo:
    """The host's handshake with a scripted device, both ends closed after it: the DeviceInfo it returned."""
    hw = SerialHardware(daq.port)
    try:
        return hw.handshake(rate_hz, watchdog_ms)
    finally:
        hw.close()
        daq.close()


@pytest.mark.parametrize(("cause", "words", "warned"), [
    (fp.ResetCause.POWER_ON, "power-on", None),
    (fp.ResetCause.WATCHDOG, "watchdog reset", "reset by its watchdog"),
    (fp.ResetCause.FAULT, "fault reset", "after a fault in its firmware"),
])
def test_the_reset_cause_is_said_on_connect(cause: fp.ResetCause, words: str, warned: str | None) -> None:
    """HELLO_ACK's reset cause reaches the user: in the log's metadata always, as a warning when the device's last
    start was its watchdog's or its fault handler's (a hung or crashed firmware the user must hear about)."""
    from furuta_rt.config import load_rig
    from furuta_rt.runtime.daemon import _check_device

    info = _handshake_with(ScriptedDaq({"reset_cause": int(cause), "actuator_full_scale": 2.0}), 500, 20)
    assert info.reset_cause == words and info.metadata()["reset_cause"] == words
    warnings: list[str] = []
    _check_device(info, load_rig("thesis"), warnings)
    if warned is None:
        assert not any("last reset" in w for w in warnings), warnings
    else:
        assert any(warned in w for w in warnings), warnings


def test_handshake_configures_rate_and_watchdog_and_reads_the_calibration() -> None:
    daq = ScriptedDaq({"sample_rate_hz": 1000, "theta_offset_counts": -12, "theta_dot_offset_counts": 5})
    info = _handshake_with(daq, 500, 40)
    configs = [m for m in daq.received if isinstance(m, fp.Config)]
    assert configs == [fp.Config(rate_hz=500, watchdog_ms=40)], "HELLO_ACK said 1000 Hz: CONFIG asks for 500"
    assert (info.rate_hz, info.watchdog_ms, info.firmware, info.actuator_kind) == (500, 40, "1.2.3", "torque")
    cal = info.calibration
    assert cal.theta_offset_counts == -12 and info.theta_dot_offset_counts == 5 and cal.phi_counts_per_rev == 4096
    assert cal.theta_rad_per_count == pytest.approx(1e-4, rel=1e-7)  # binary32 on the wire
    meta = info.metadata()
    assert meta["device_id"] == "0x00000007" and meta["applied_rate_hz"] == "500"


def test_a_retried_hello_answered_twice_follows_the_session_the_device_streams() -> None:
    """The device answers the first HELLO after the host's 100 ms retry: both HELLOs are answered and the second
    restarts the session at seq 0. The host takes the second ACK's session: its first tick is the restarted stream's
    seq 0, not a SAMPLE of the replaced session (whose seq 0 → 0 would trip as a device reset, as a slow qemu boot
    did in CI)."""
    daq = ScriptedDaq({}, slow_first_hello=True)
    hw = SerialHardware(daq.port)
    try:
        info = hw.handshake(500, 20)
        first = hw.read(0.5)
        assert first is not None
        hw.write(first.seq, 100, int(fp.CommandFlags.ENABLE))
    finally:
        hw.close()
        daq.close()
    hellos = [m for m in daq.received if isinstance(m, fp.Hello)]
    assert len(hellos) >= 2 and info.ack.nonce == hellos[-1].nonce
    commands = [m for m in daq.received if isinstance(m, fp.Command)]  # bound to the session the device streams
    assert [c.session for c in commands] == [hellos[-1].nonce], commands
    assert first is not None and (first.seq, first.t_us) == (0, 50_000)


def test_a_frame_the_port_cut_short_stalls_once_and_the_next_starts_with_a_delimiter() -> None:
    """A device that stops reading: frames fill the pty until one goes out in part; after the write timeout that
    is LinkLost (not gone: the port is there), and the next frame starts with a 0x00 so the device's decoder drops
    the cut one instead of merging it into the next (PROTOCOL.md §2.1)."""
    import tty

    from furuta_rt.runtime.hardware import LinkLost

    device, host = os.openpty()
    tty.setraw(device)
    tty.setraw(host)
    hw = SerialHardware(os.ttyname(host))
    hw.open()
    try:
        frame = bytes(range(1, 200))  # no 0x00 (a COBS frame's body); 199 bytes: the pty's capacity is no multiple
        sent = 0
        with pytest.raises(LinkLost, match="stalled: the port took") as lost:
            while sent < 10_000:
                hw._send(frame, timeout=0.05)
                sent += 1
        assert lost.value.gone is False and hw.write_errors == 1
        os.set_blocking(device, False)
        got = b""
        with contextlib.suppress(BlockingIOError):
            while chunk := os.read(device, 65536):
                got += chunk
        cut = len(got) - sent * len(frame)
        assert 0 < cut < len(frame) and got == frame * sent + frame[:cut], (sent, len(got))
        hw._send(frame)
        assert os.read(device, 4096) == b"\x00" + frame
        hw._send(frame)  # the delimiter once, not on every frame after it
        assert os.read(device, 4096) == frame
    finally:
        hw.close()
        os.close(device)


def test_missing_device_is_a_one_line_user_error() -> None:
    with pytest.raises(UserError, match=r"does not exist.*--mock"):
        SerialHardware("/dev/furuta-no-such-device").open()


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        ([], "--port DEV"),
        (["--mock", "--duration", "-1"], "--duration"),
        (["--port", "/dev/null", "--mock-effect", "arm_coulomb.Fc=0.3"], "only apply with --mock"),
        (["--mock", "--rate", "0"], "--rate"),
        (["--mock", "--cpu", "4096"], "--cpu 4096: not a CPU this process may run on"),
        (["--port", "/dev/furuta-no-such-device", "--duration", "1"], "does not exist"),
        (["--mock", "--config", "/nonexistent.toml"], "does not exist"),
    ],
)
def test_cli_user_errors_exit_2_with_one_line(args: list[str], needle: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli_main(["run", "--no-tui", *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("furuta-rt run: error:") and needle in err[0], err


def test_loop_result_rates() -> None:
    r = LoopResult(ticks=501, host_span_s=1.0, device_span_s=1.0)
    assert r.rate_hz == 500.0 and r.device_rate_hz == 500.0
    assert math.isnan(LoopResult().rate_hz)


def test_dashboard_snapshots_at_most_10_hz_and_render(rig: RigConfig) -> None:
    from rich.console import Console

    from furuta_rt.runtime.dashboard import render

    dev = SimDevice(rig)
    snaps: list[dict] = []

    class Snaps:
        def put_nowait(self, item: dict) -> None:
            snaps.append(item)

    loop, _ = make_loop(rig, dev, duration=2.0)
    loop.dashboard = Snaps()
    loop.run()
    assert len(snaps) == 2 * RATE // loop.settings.snapshot_ticks == 20, "10 per second of device time"
    last = snaps[-1]
    assert last["state"] == "balancing" and last["ticks"] == 2 * RATE and last["mode"] == "none"
    console = Console(record=True, width=120)
    console.print(render(last))
    text = console.export_text()
    for needle in ("BALANCING", "loop rate", "jitter max", "overruns", "compensation", "gaps / CRC"):
        assert needle in text, text
    console.print(render(None))
    assert "waiting for the device" in console.export_text()


def test_the_loop_creates_no_reference_cycles(rig: RigConfig) -> None:
    """The daemon runs with the cyclic GC frozen and disabled: every tick's garbage must go by refcount."""
    import gc

    dev = SimDevice(rig)
    loop, _ = make_loop(rig, dev, duration=0.2)
    loop.run()  # warm-up: first-tick allocations (histograms, batches) are not per-tick garbage
    dev = SimDevice(rig)
    loop, _ = make_loop(rig, dev, duration=2.0)
    gc.collect()
    gc.disable()
    try:
        loop.run()
        unreachable = gc.collect()
    finally:
        gc.enable()
    assert unreachable == 0, f"{unreachable} objects in reference cycles after 1000 ticks"


def test_a_hanging_pendulum_is_told_once_why_it_does_not_arm(rig: RigConfig) -> None:
    """Issue 15 item 8: a host that finds the pendulum down stays idle; after 1 s it says once why (not a
    silent run that ends "never balanced"), and never drives the actuator."""
    dev = SimDevice(rig, x0=(math.pi, 0.0, 0.0, 0.0))
    loop, sink = make_loop(rig, dev, duration=3.0)
    r = loop.run()
    notes = [e for e in sink.events() if "not armed" in e]
    assert len(notes) == 1 and "|θ| = 3.14" in notes[0] and "upright" in notes[0], sink.events()
    assert r.balancing_ticks == 0 and not [w for w in dev.writes if w[3] & ENABLE]
    printed = [e for e in dev.journal if e[0] == "print" and "not armed" in e[2]]
    assert len(printed) == 1 and printed[0][1] == "WARNING"


class _TwiceStallingController(_StallingController):
    """The stall of ``_StallingController``, and another one on the SAMPLE that would end the run of skipped periods
    (the newest of the burst the first stall left waiting)."""

    second_stall_t = _StallingController.stall_at_t + 15 / RATE

    def update(self, m: Measurement) -> Any:
        if abs(m.t - self.second_stall_t) < 1e-6:
            time.sleep(0.030)
        return super().update(m)


def test_a_sample_that_ends_a_skipped_run_and_ages_too_keeps_one_overrun(rig: RigConfig) -> None:
    """The SAMPLE after a stall's burst ages as well (a second stall between its read and write): it is skipped, the
    run of skipped periods goes on to the next SAMPLE, and the whole run is still one overrun."""
    stalled = round(_StallingController.stall_at_t * RATE)
    dev = SimDevice(rig, bursts={stalled + 1: 15, stalled + 16: 15})
    ctrl = Controller.from_rig(rig)
    ctrl.__class__ = _TwiceStallingController
    loop, sink = make_loop(rig, dev, duration=2.0, controller=ctrl, stale_age_periods=LoopSettings.stale_age_periods)
    r = loop.run()
    answered = {w[1] for w in dev.writes}
    assert set(range(stalled, stalled + 30)).isdisjoint(answered), "no COMMAND from either aged SAMPLE's period"
    timing = {rec[F["seq"]]: rec for rec in sink.ticks()}
    before = max(seq for seq in answered if seq < stalled)
    after = min(seq for seq in answered if seq >= stalled + 30)
    skipped = {seq for seq, rec in timing.items() if rec[F["latency_us"]] == -1.0}
    assert set(range(before + 1, after)) <= skipped and r.skipped_periods == len(skipped)
    assert timing[after][F["overruns"]] - timing[before][F["overruns"]] == 1, "one run of skipped periods, one overrun"
    assert r.end == "duration"
