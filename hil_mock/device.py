"""VirtualDevice: the firmware (hil_mock.firmware) served over a raw pseudo-terminal in real time.

The loop, once per timer period (pacing "realtime"):

    wait for the absolute deadline t_base + device clock (sleep, then a short spin)
    if a whole period or more late: the skipped timer periods run the plant with the output held,
        TICK_OVERRUN is reported, seq is NOT skipped (as an MCU timer ISR that overran)
    scheduled faults due → applied
    read everything the host sent (non-blocking), through the link faults, into the firmware
    firmware tick (SAMPLE out, COMMAND applied, plant advanced one period)
    frames out through the link faults and the optional delay line, written non-blocking

Pacing "free" runs streaming ticks back to back (benchmarks); "lockstep" starts each streaming tick as
soon as the COMMAND answering the previous SAMPLE arrived (deterministic runs on a loaded machine, a
device slower than real time included; a SAMPLE left unanswered for LOCKSTEP_TIMEOUT_S, or one the host made moot by
a HELLO or a CONFIG after it, is a late command and the device ticks on, still in lockstep). Idle, both pace in real
time. Timing statistics cover streaming ticks only.

In lockstep the default device (C firmware core, compiled plant) serves the common round — tick, write, plant,
wait for the COMMAND, read it — in C (hil_mock.c_firmware.CFirmware.serve_lockstep), round for round what this
loop does, and this loop takes over wherever it has something to do: a fault due or requested, a stop, a signal,
link faults, a hang-up, a partial write, a new session, the noise block, a new actuator count (``compiled_ticks``
counts the ticks the C served).
"""

from __future__ import annotations

import contextlib
import errno
import math
import os
import queue
import select
import sys
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any

from furuta_rt.cpu_idle import hold_wakeup_latency
from furuta_rt.cpu_placement import pin_cpu
from furuta_rt.errors import UserError
from furuta_rt.model.rig import RigModel
from hil_mock.c_firmware import AFTER_WRITE, AWAITING, CFirmware, make_firmware
from hil_mock.config import MockConfig
from hil_mock.faults import FaultEvent, LinkFaults
from hil_mock.ptyport import open_raw_pty
from hil_mock.timing import DeadlineWaiter, TickTiming, raise_priority, set_timer_slack

TX_BACKLOG_MAX = 4096
"""Bytes the device buffers when the host does not read; beyond it whole frames are dropped (TX_OVERFLOW)."""
LOCKSTEP_TIMEOUT_S = 0.1
"""How long a lockstep device waits for the COMMAND answering its SAMPLE before it ticks on without it (the output held,
as the firmware does for a late command). A host may leave a SAMPLE unanswered (one that aged in a starved host, or
the first one, which shares a read with the HELLO_ACK); the wait stays well inside the host's link timeout (0.5 s by
default), so such a SAMPLE costs one late command, never a link loss."""
IN_PROCESS_SWITCH_INTERVAL_S = 2e-4
READ_BYTES = 4096  # hil_mock/csrc/device.c HIL_READ_BYTES
COMPILED_ROUNDS = 256
"""Lockstep rounds the C serves before it hands the loop back (its counters then reach ``stats``): ~10 ms at 25x."""


@dataclass(frozen=True, slots=True)
class DeviceStats:
    """Snapshot of the device's counters and timing (times in µs unless named _s)."""

    rate_hz: int
    pacing: str
    priority: str
    ticks: int
    samples_sent: int
    late_ticks: int
    late_threshold_us: float
    overruns: int
    missed_periods: int
    worst_lateness_us: float
    mean_lateness_us: float
    p99_lateness_us: float
    worst_work_us: float
    mean_work_us: float
    commands_rx: int
    commands_applied: int
    commands_discarded: int
    watchdog_trips: int
    crc_errors: int
    frame_errors: int
    frames_rx: int
    status_sent: int
    handshakes: int
    handshakes_refused: int
    hangups: int
    resets: int
    stalls: int
    tx_frames_dropped: int
    tx_bytes_corrupted: int
    tx_bytes_dropped: int
    rx_bytes_corrupted: int
    rx_bytes_dropped: int
    wall_s: float
    plant_s: float
    cpu_s: float = 0.0  # CPU time of the device's loop (its thread) over wall_s
    pty_reads: int = 0  # system calls on the pty: read (one that found nothing included), write, select
    pty_writes: int = 0
    pty_selects: int = 0
    spin_us: float = 0.0  # the busy wait before a real-time deadline, as learned by the end
    friction_steps: int = 0
    arm_coulomb: float = 0.0  # the arm's Coulomb level at the end (after any friction_step), N m
    cpu: int | None = None  # the CPU the device thread was pinned to (None: not pinned)
    pushes: int = 0
    compiled_ticks: int = 0  # ticks served by the compiled lockstep round (CFirmware.serve_lockstep)
    clock_origin_s: float = 0.0  # the device clock's zero on time.perf_counter (CLOCK_MONOTONIC): in real-time pacing a
    # SAMPLE's device time t is at clock_origin_s + t on this machine's clock (what a kernel trace is timed by)

    @property
    def realtime_factor(self) -> float:
        return self.plant_s / self.wall_s if self.wall_s > 0 else 0.0

    @property
    def cpu_per_tick_us(self) -> float:
        """The loop's CPU per streaming tick, µs (pacing waits that spin included, sleeps not)."""
        return self.cpu_s / self.ticks * 1e6 if self.ticks else 0.0

    def as_dict(self) -> dict[str, Any]:
        return {**asdict(self), "realtime_factor": self.realtime_factor, "cpu_per_tick_us": self.cpu_per_tick_us}

    def summary(self) -> str:
        """Human-readable block, as printed by ``hil-mock`` on exit."""
        return "\n".join((
            f"hil-mock: {self.ticks} ticks at {self.rate_hz} Hz ({self.pacing}, {self.priority} priority"
            f"{'' if self.cpu is None else f', CPU {self.cpu}'}), "
            f"{self.samples_sent} SAMPLEs, plant {self.plant_s:.3f} s in {self.wall_s:.3f} s wall",
            f"hil-mock: timing: late ticks {self.late_ticks} (> {self.late_threshold_us:.0f} µs), overruns "
            f"{self.overruns} ({self.missed_periods} periods skipped), lateness worst {self.worst_lateness_us:.0f} µs "
            f"mean {self.mean_lateness_us:.1f} µs p99 < {self.p99_lateness_us:g} µs, work worst "
            f"{self.worst_work_us:.0f} µs mean {self.mean_work_us:.1f} µs, CPU {self.cpu_per_tick_us:.1f} µs per tick",
            f"hil-mock: link: commands rx {self.commands_rx} applied {self.commands_applied} discarded "
            f"{self.commands_discarded}, watchdog trips {self.watchdog_trips}, rx frames {self.frames_rx} crc errors "
            f"{self.crc_errors} frame errors {self.frame_errors}, handshakes {self.handshakes} (refused "
            f"{self.handshakes_refused}), hangups {self.hangups}, tx frames dropped {self.tx_frames_dropped}",
            f"hil-mock: faults: resets {self.resets}, stalls {self.stalls}, pushes {self.pushes}, tx bytes corrupted "
            f"{self.tx_bytes_corrupted} dropped {self.tx_bytes_dropped}, rx bytes corrupted {self.rx_bytes_corrupted} "
            f"dropped {self.rx_bytes_dropped}"
            + (f", friction steps {self.friction_steps} (arm Coulomb now {self.arm_coulomb:g} N m)"
               if self.friction_steps else ""),
        ))


class VirtualDevice:
    """The simulated rig's DAQ on a pseudo-terminal. ``port`` is the path a host opens.

    Use ``start()``/``stop()`` (background thread) or ``with VirtualDevice(cfg) as dev:``; ``run()``
    serves in the calling thread until ``stop()`` (from another thread or a signal handler).
    Fault methods (``stall``, ``reset``, ``disconnect``, ``mute``, ``deafen``, ``push``) are thread-safe and act
    at the next tick; ``link`` holds the live byte-fault rates.
    """

    def __init__(self, config: MockConfig | None = None) -> None:
        self.config = config or MockConfig()
        rig = self.config.load_rig()
        model = RigModel.from_config(rig, self.config.effects)
        self.rig = rig
        dev = self.config.device
        self.firmware = make_firmware(dev.firmware, rig, model, dev, self.config.rate_hz(rig))
        f = self.config.faults
        self.link = LinkFaults(f.corrupt_rate, f.drop_rate, f.rx_corrupt_rate, f.rx_drop_rate, f.seed)
        self.delay_s = f.delay_ms / 1000.0
        self.pacing = dev.pacing
        self.waiter = DeadlineWaiter(dev.spin_us * 1e-6)
        self._events: list[FaultEvent] = f.events()
        if model.arm_friction.lugre is not None and any(e.kind == "friction_step" for e in self._events):
            raise UserError("fault friction_step sets the arm's Coulomb level; this rig's arm friction is LuGre "
                            "(arm_lugre): give the step as a Coulomb rig or drop the fault")
        self.friction_steps = 0
        self._actions: queue.SimpleQueue[Callable[[], None]] = queue.SimpleQueue()
        self._delayed: deque[tuple[float, bytes]] = deque()
        self._backlog = bytearray()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._saved_switch: float | None = None
        self._fd: int | None = None
        self.port = ""
        self.connected = False
        self.disconnected = False
        self.tx_frames_dropped = 0
        self.stalls = 0
        self.pushes = 0
        self.priority = "normal"
        self.cpu: int | None = None
        self.pty_reads = self.pty_writes = self.pty_selects = 0
        self._drained = False  # the last read ended short: the pty was empty
        threshold = dev.late_threshold_us * 1e-6 if dev.late_threshold_us else 0.25 / self.firmware.rate_hz
        self.timing = TickTiming(threshold)
        self._t_start = 0.0
        self._t_end: float | None = None
        self._cpu_clock: int | None = None
        self._cpu_start = self._cpu_s = 0.0
        fw = self.firmware
        self._compiled = fw if isinstance(fw, CFirmware) and fw.fused and self.pacing == "lockstep" else None
        self.compiled_ticks = 0
        self._fd, self.port = open_raw_pty()
        self._poller = select.poll()  # registered once: no fd sets built per wait, as select.select does
        self._poller.register(self._fd, select.POLLIN)

    # ------------------------------------------------------------ lifecycle
    def start(self) -> VirtualDevice:
        """Serve in a background thread; returns self."""
        if self._thread is not None:
            raise RuntimeError("VirtualDevice already started")
        # A busy host thread in this process would hold the GIL for up to the switch interval (5 ms by
        # default) whenever the device thread wakes up; 0.2 ms keeps in-process ticks on time.
        self._saved_switch = sys.getswitchinterval()
        sys.setswitchinterval(min(self._saved_switch, IN_PROCESS_SWITCH_INTERVAL_S))
        self._thread = threading.Thread(target=self.run, name=f"hil-mock {self.port}", daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout: float = 5.0) -> None:
        """Stop serving, zero the output, close the pty (the host sees a hang-up)."""
        self._stop.set()
        self._wake()
        thread = self._thread
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout)
        if thread is None or not thread.is_alive():
            self._close()
        if self._saved_switch is not None:
            sys.setswitchinterval(self._saved_switch)
            self._saved_switch = None

    def request_stop(self) -> None:
        """Ask ``run()`` to return after the current tick (safe from a signal handler)."""
        self._stop.set()
        self._wake()

    def _wake(self) -> None:
        """Hand the loop back from the compiled lockstep rounds: a stop or a fault was requested."""
        if self._compiled is not None:
            self._compiled.interrupt_lockstep()

    def _act(self, action: Callable[[], None]) -> None:
        self._actions.put(action)
        self._wake()

    def __enter__(self) -> VirtualDevice:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def _close(self) -> None:
        fd, self._fd = self._fd, None
        if fd is not None:
            with contextlib.suppress(OSError):
                os.close(fd)
        if self._t_end is None:
            self._t_end = time.perf_counter()

    # ------------------------------------------------------------ faults (any thread)
    def stall(self, seconds: float) -> None:
        """The firmware hangs for ``seconds``: no ticks, reads or writes; the plant runs on, output held."""
        self._act(lambda: self._do_stall(seconds))

    def reset(self) -> None:
        """Reboot: output zero, faults and configuration cleared, idle until a new HELLO (seq from 0)."""
        self._act(self._do_reset)

    def disconnect(self) -> None:
        """Close the pty master: the host's port reads EOF/fails; the device stops serving."""
        self._act(self._do_disconnect)

    def mute(self, seconds: float) -> None:
        """Lose every device→host byte for ``seconds``."""
        self._act(lambda: self._timed_flag("muted", seconds))

    def deafen(self, seconds: float) -> None:
        """Lose every host→device byte for ``seconds``."""
        self._act(lambda: self._timed_flag("deafened", seconds))

    def push(self, theta_dot_jump: float = 0.0) -> None:
        """An impulse on the pendulum: θ̇ jumps by ``theta_dot_jump`` rad/s (0: 2·√(ε/α), a full turn's energy)."""
        self._act(lambda: self._do_push(theta_dot_jump))  # at the next tick: the plant's state is the loop's (or C's)

    def _do_push(self, theta_dot_jump: float) -> None:
        p = self.firmware.sim.model.plant.p
        self.firmware.sim.theta_dot += theta_dot_jump or 2.0 * math.sqrt(p.epsilon / p.alpha)
        self.pushes += 1

    def _do_stall(self, seconds: float) -> None:
        self.stalls += 1
        time.sleep(seconds)
        fw = self.firmware
        fw.skip(round(seconds * 1e9 / fw.period_ns))

    def _do_reset(self) -> None:
        self.firmware.reboot()
        self._delayed.clear()
        self._backlog.clear()

    def _do_disconnect(self) -> None:
        self.firmware.hangup()
        self.disconnected = True
        self._close()
        self._stop.set()

    def _timed_flag(self, name: str, seconds: float) -> None:
        setattr(self.link, name, True)
        self._events.append(FaultEvent(f"end_{name}", self.firmware.plant_time + seconds))
        self._events.sort(key=lambda e: e.at)

    def _run_due_events(self) -> None:
        fw = self.firmware
        if fw.plant_start_ns is None:
            return
        now = fw.plant_time
        while self._events and self._events[0].at <= now:
            ev = self._events.pop(0)
            if ev.kind == "stall":
                self._do_stall(ev.duration)
            elif ev.kind == "reset":
                self._do_reset()
            elif ev.kind == "disconnect":
                self._do_disconnect()
            elif ev.kind == "mute":
                self._timed_flag("muted", ev.duration)
            elif ev.kind == "deaf":
                self._timed_flag("deafened", ev.duration)
            elif ev.kind == "friction_step":
                values = dict(ev.params)
                fw.set_arm_coulomb(values["Fc"], values.get("Fs"))
                self.friction_steps += 1
            elif ev.kind == "push":
                self._do_push(ev.duration)
            elif ev.kind.startswith("end_"):
                setattr(self.link, ev.kind[4:], False)

    # ------------------------------------------------------------ I/O
    def _read(self) -> None:
        fd = self._fd
        if fd is None:
            return
        fw = self.firmware
        while True:
            self.pty_reads += 1
            try:
                data = os.read(fd, READ_BYTES)
            except BlockingIOError:
                self.connected = True
                return
            except OSError as err:
                if err.errno == errno.EIO:  # no host has the port open
                    if self.connected:
                        self.connected = False
                        self._hangup()
                    return
                raise
            if not data:
                return
            self.connected = True
            short = len(data) < READ_BYTES
            if self.link.active:
                data = self.link.rx(data)
            fw.receive(data)
            if short:  # a short read emptied the pty: no second read to learn it is empty
                self._drained = True
                return

    def _hangup(self) -> None:
        self.firmware.hangup()
        self._delayed.clear()
        self._backlog.clear()

    def _write(self, now: float) -> None:
        fw = self.firmware
        link = self.link
        if fw.tx and not self._backlog and not self.delay_s and not link.active and self._fd is not None:
            wire = b"".join(fw.tx) if len(fw.tx) > 1 else fw.tx[0]  # the common tick: straight to the pty
            fw.tx.clear()
            self.pty_writes += 1
            try:
                n = os.write(self._fd, wire)
            except BlockingIOError:
                n = 0
            except OSError as err:
                if err.errno != errno.EIO:
                    raise
                return
            if n < len(wire):
                self._queue_wire(wire[n:])
            return
        if fw.tx:
            for frame in fw.tx:
                wire = link.tx(frame) if link.active else frame
                if self.delay_s:
                    self._delayed.append((now + self.delay_s, wire))
                else:
                    self._queue_wire(wire)
            fw.tx.clear()
        delayed = self._delayed
        while delayed and delayed[0][0] <= now:
            self._queue_wire(delayed.popleft()[1])
        if self._backlog and self._fd is not None:
            self.pty_writes += 1
            try:
                n = os.write(self._fd, self._backlog)
            except BlockingIOError:
                return
            except OSError as err:
                if err.errno != errno.EIO:
                    raise
                self._backlog.clear()
                return
            del self._backlog[:n]

    def _queue_wire(self, wire: bytes) -> None:
        if len(self._backlog) + len(wire) > TX_BACKLOG_MAX:
            self.tx_frames_dropped += 1
            self.firmware.note_tx_overflow()
        else:
            self._backlog += wire

    def _wait_readable(self, timeout: float) -> bool:
        fd = self._fd
        if fd is None:
            return False
        self.pty_selects += 1
        try:
            return bool(self._poller.poll(timeout * 1000.0))  # POLLHUP (no host) too: the read then sees EIO
        except (OSError, ValueError):
            return False

    # ------------------------------------------------------------ loop
    def run(self) -> None:
        """Serve until ``stop()`` or a disconnect fault (blocking)."""
        set_timer_slack()
        qos = None
        if self.config.device.priority == "realtime" and self.pacing != "free":  # free-running must not hog a core
            self.priority = raise_priority()
            qos, _ = hold_wakeup_latency(0)  # a device that keeps time answers at once; without it, as before
        if self.config.device.cpu is not None:  # on the host loop's CPU: their round trip waits for no other CPU
            self.cpu, cpu_warning = pin_cpu(self.config.device.cpu)
            if cpu_warning:
                print(f"hil-mock: warning: {cpu_warning}", file=sys.stderr, flush=True)
        fw = self.firmware
        timing = self.timing
        pc = time.perf_counter
        wait = self.waiter.wait
        self._t_start = t_base = pc() - fw.clock_ns * 1e-9
        self._t_end = None
        self._cpu_clock = time.pthread_getcpuclockid(threading.get_ident())
        self._cpu_start = time.clock_gettime(self._cpu_clock)
        realtime = True
        drained = False
        stop = self._stop
        actions = self._actions
        try:
            while not stop.is_set():
                while not actions.empty():
                    actions.get_nowait()()
                if self._events:
                    self._run_due_events()
                if self._fd is None:
                    break
                if drained and not realtime and self._compiled is not None and self._compiled_round_ready():
                    drained, realtime, t_base = self._serve_compiled(t_base)
                    continue
                streaming = fw.streaming
                if realtime:
                    deadline = t_base + fw.clock_ns * 1e-9
                    wait(deadline, streaming)
                    now = pc()
                    lateness = now - deadline
                    period = fw.period_ns * 1e-9
                    if lateness >= period:
                        missed = int(lateness / period)
                        fw.skip(missed)
                        if streaming:
                            timing.overruns += 1
                            timing.missed_periods += missed
                        if self._events:  # a fault due within the skipped periods comes before this tick
                            self._run_due_events()
                            if self._fd is None:
                                break
                else:
                    now = pc()
                    t_base = now - fw.clock_ns * 1e-9
                    lateness = 0.0
                if drained:  # lockstep: the wait for the COMMAND just emptied the pty; a read would find nothing
                    drained = False
                else:
                    self._read()
                streaming = fw.streaming
                fw.tick(advance=False)
                self._write(now)  # the SAMPLE leaves at the tick, as the firmware's DMA sends it
                drained, realtime = self._end_tick(now, lateness, streaming)
        finally:
            with contextlib.suppress(OSError):  # what the host sent last (its STOP) reaches the firmware before it stops
                self._read()
            fw.hangup()
            self._close()
            if qos is not None:
                os.close(qos)
            self._cpu_s = time.clock_gettime(self._cpu_clock) - self._cpu_start
            self._cpu_clock = None

    def _end_tick(self, now: float, lateness: float, streaming: bool) -> tuple[bool, bool]:
        """The tick after its frames went out: the plant advanced, the tick timed, the next one's pacing; returns
        (the pty drained, pace in real time)."""
        fw = self.firmware
        fw.advance_plant()  # the simulator's compute: not in the link's delay
        if streaming:
            self.timing.record(lateness, time.perf_counter() - now)
        if self.pacing == "realtime" or not fw.streaming or not self.connected:
            return False, True
        if self.pacing == "free":
            return False, False
        # lockstep: the next tick when the COMMAND answering the SAMPLE just sent arrived (or waited in vain)
        return self._await_answer(time.perf_counter() + LOCKSTEP_TIMEOUT_S) and self._drained, False

    def _compiled_round_ready(self) -> bool:
        """The loop's next passes are the compiled lockstep round's to serve: streaming, connected, nothing held back
        (link faults, the delay line, a backlog, frames not yet written), no fault due at the next tick, no stop or
        fault requested since the top."""
        fw = self._compiled
        assert fw is not None
        if fw.tx or self._backlog or self._delayed or self.delay_s or self.link.active or not self.connected:
            return False
        if not fw.streaming or fw.substeps_done >= self._fault_substep():
            return False
        fw.interrupt_lockstep(False)  # cleared before the look at the requests: none is missed
        return not self._stop.is_set() and self._actions.empty()

    def _fault_substep(self) -> int:
        """The first plant substep at which the next scheduled fault is due (``plant_time >= at``, as
        ``_run_due_events`` decides it); far away without one."""
        if not self._events:
            return 1 << 62
        hz, at = self.firmware.substep_hz, self._events[0].at
        n = math.ceil(at * hz)
        while n > 0 and (n - 1) / hz >= at:
            n -= 1
        while n / hz < at:
            n += 1
        return n

    def _serve_compiled(self, t_base: float) -> tuple[bool, bool, float]:
        """Lockstep rounds in C (CFirmware.serve_lockstep) up to the next scheduled fault; then this loop's pass from
        where the C left it. Returns the loop's (drained, realtime, t_base)."""
        fw = self._compiled
        assert fw is not None and self._fd is not None
        s, rest = fw.serve_lockstep(self._fd, COMPILED_ROUNDS, self._fault_substep(), LOCKSTEP_TIMEOUT_S)
        self.compiled_ticks += s.rounds
        self.pty_reads += s.reads
        self.pty_writes += s.writes
        self.pty_selects += s.selects
        self.timing.record_lockstep(s.timed_rounds, s.sum_work_s, s.worst_work_s)
        pc = time.perf_counter
        mono = time.clock_gettime_ns(time.CLOCK_MONOTONIC)  # the C's clock (perf_counter's may have another origin)
        now = pc() - (mono - s.round_start_ns) * 1e-9  # the last tick's start
        if s.rounds:
            t_base = now - s.round_clock_ns * 1e-9
        if s.phase == AFTER_WRITE:  # the tick's frames went out (all or part); the loop's pass goes on from there
            if s.error:
                raise OSError(s.error, os.strerror(s.error))
            if rest:
                self._queue_wire(rest)
            drained, realtime = self._end_tick(now, 0.0, True)  # the C enters and goes on only while streaming
            return drained, realtime, t_base
        if s.phase == AWAITING:  # the wait for the COMMAND, from where the C left it
            until = pc() + (s.until_ns - mono) * 1e-9
            return self._await_answer(until, bool(s.drained)) and self._drained, False, t_base
        return bool(s.drained), bool(s.realtime), t_base

    def _await_answer(self, until: float, drained: bool = False) -> bool:
        fw = self.firmware
        self._drained = drained
        while not fw.answered and not fw.reconfigured:  # a HELLO or CONFIG: the host will not answer it
            if self._stop.is_set() or self._fd is None:
                return True
            remaining = until - time.perf_counter()
            if remaining <= 0:
                return False
            if self._delayed or self._backlog:  # frames held by the delay fault or a full pty still have to go out
                self._write(time.perf_counter())
                remaining = min(remaining, 0.001)
            if self._wait_readable(min(remaining, 0.05)):
                self._read()
                if not self.connected:
                    return False
        return True

    # ------------------------------------------------------------ stats
    def _cpu_used(self) -> float:
        """CPU seconds of the serving thread: so far while it runs, else over its run."""
        clock = self._cpu_clock
        if clock is None:
            return self._cpu_s
        try:
            return time.clock_gettime(clock) - self._cpu_start
        except OSError:  # the thread just ended
            return self._cpu_s

    @property
    def stats(self) -> DeviceStats:
        fw = self.firmware
        t = self.timing
        d = fw.decoder
        link = self.link
        end = self._t_end if self._t_end is not None else time.perf_counter()
        n = max(t.ticks, 1)
        return DeviceStats(
            rate_hz=fw.rate_hz,
            pacing=self.pacing,
            priority=self.priority,
            cpu=self.cpu,
            ticks=t.ticks,
            samples_sent=fw.samples_sent,
            late_ticks=t.late_ticks,
            late_threshold_us=t.late_threshold_s * 1e6,
            overruns=t.overruns,
            missed_periods=t.missed_periods,
            worst_lateness_us=t.worst_lateness_s * 1e6,
            mean_lateness_us=t.sum_lateness_s / n * 1e6,
            p99_lateness_us=t.percentile_us(0.99),
            worst_work_us=t.worst_work_s * 1e6,
            mean_work_us=t.sum_work_s / n * 1e6,
            commands_rx=fw.commands_rx,
            commands_applied=fw.commands_applied,
            commands_discarded=fw.commands_discarded,
            watchdog_trips=fw.watchdog_trips,
            crc_errors=d.crc_errors,
            frame_errors=d.errors - d.crc_errors,
            frames_rx=d.frames_ok,
            status_sent=fw.status_sent,
            handshakes=fw.handshakes,
            handshakes_refused=fw.handshakes_refused,
            hangups=fw.hangups,
            resets=fw.reboots,
            stalls=self.stalls,
            tx_frames_dropped=self.tx_frames_dropped,
            tx_bytes_corrupted=link.tx_corrupted,
            tx_bytes_dropped=link.tx_dropped,
            rx_bytes_corrupted=link.rx_corrupted,
            rx_bytes_dropped=link.rx_dropped,
            clock_origin_s=self._t_start,
            wall_s=max(end - self._t_start, 0.0) if self._t_start else 0.0,
            plant_s=fw.plant_time,
            cpu_s=self._cpu_used(),
            friction_steps=self.friction_steps,
            arm_coulomb=fw.model.arm_friction.dry.sliding_level if fw.model.arm_friction.dry is not None else 0.0,
            pushes=self.pushes,
            compiled_ticks=self.compiled_ticks,
            pty_reads=self.pty_reads,
            pty_writes=self.pty_writes,
            pty_selects=self.pty_selects,
            spin_us=self.waiter.spin_s * 1e6,
        )
