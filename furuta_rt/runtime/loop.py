"""The control loop (the manager): read → update → write, clocked by the device's SAMPLE stream.

Per tick:

1. ``read``: block on the next SAMPLE (no SAMPLE within ``link_timeout_s`` = link loss; for a rig
   that is safety.link_loss_periods periods);
2. convert counts to SI with the device's calibration (HELLO_ACK);
3. the supervisor decides the state; at arming ``Controller.reset(φ)``; ``Controller.update`` when
   balancing or swinging up, ``Controller.hold`` otherwise (the replay rule of furuta_rt.io.log_schema);
   with a swing-up the start-up calibration (furuta_rt.runtime.calibration) is taken while calibrating and
   applied to θ and φ from then on (the log keeps the device's readings and the calibration as metadata),
   and the controller's catch and fall move the supervisor between swinging_up and balancing;
   with a designed experiment (``Controller.excitation``) each segment's start is logged as an event
   ("experiment: segment k/n ..."), and the plan's end ends the run; a hanging experiment's plan drives the
   actuator open loop through the same ``update`` in the supervisor's ``open_loop`` state;
4. ``write`` one COMMAND (ENABLE only when balancing, swinging up or open loop). A sample that is already stale (a newer one is
   waiting: the period was missed) runs through the controller, so the observer keeps the device's
   time step, but gets no COMMAND: whole periods are skipped, commands are never burst;
5. a tick record goes into the current batch; every ``batch_ticks`` ticks the batch is handed to the
   logger process with ``put_nowait`` (a full queue drops the batch and counts it).

On a trip, a signal, link loss or an exception the actuator is zeroed *before* anything is logged or
printed: a trip inside a tick answers its SAMPLE with u = 0 (ENABLE clear); every other way out calls
``hw.stop()`` at once, which answers the newest SAMPLE with u = 0 when a device following PROTOCOL.md §6
accepts it (a COMMAND answering an already answered SAMPLE is discarded) and sends STOP, which zeroes
the output at once (§4). If that cannot be sent, an ERROR event says so.
"""

from __future__ import annotations

import contextlib
import math
import queue
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

from firmware_protocol import COMMAND_FULL_SCALE, FAULT_MASK, CommandFlags, StatusFlags
from furuta_rt.config import SwingUpConfig
from furuta_rt.controller.controller import Controller, Measurement
from furuta_rt.runtime import signals as stop_signals
from furuta_rt.runtime.calibration import CALIBRATION_METADATA, CalibrationWindow, StartupCalibration
from furuta_rt.runtime.hardware import HardwareInterface, LinkLost
from furuta_rt.runtime.records import STATE_NAMES, TICK_RECORD
from furuta_rt.runtime.supervisor import State, Supervisor, TripReason
from furuta_rt.runtime.timing import DeviceClock, Histogram, RunningStats
from furuta_rt.runtime.trace import RecentTrace

__all__ = ["TICK_RECORD", "ControlLoop", "LoopResult", "LoopSettings"]

_ENABLE = int(CommandFlags.ENABLE)
_CLEAR_FAULT = int(CommandFlags.CLEAR_FAULT)
_FAULT_MASK = int(FAULT_MASK)
_COMMAND_LATE = int(StatusFlags.COMMAND_LATE)
_TICK_OVERRUN = int(StatusFlags.TICK_OVERRUN)
_BALANCING = State.BALANCING
_SWINGING = State.SWINGING_UP
_OPEN_LOOP = State.OPEN_LOOP
_CALIBRATING = State.CALIBRATING
_TRIPPED = State.TRIPPED


class Sink(Protocol):
    def put_nowait(self, item: Any) -> None: ...


@dataclass
class LoopSettings:
    rate_hz: float
    duration: float | None = None  # s of device time; None = until stopped
    link_timeout_s: float = 0.004  # no SAMPLE for this long = link loss (rig: safety.link_loss_periods periods)
    first_sample_timeout: float = 1.0  # s to wait for the stream to start
    batch_ticks: int = 50  # ticks per logger batch
    snapshot_ticks: int = 50  # ticks per dashboard snapshot (≤ 10 Hz at 500 Hz)
    stats_after_s: float = 1.0  # std θ/φ/u exclude the first second of balancing
    idle_notice_s: float = 1.0  # still idle (never armed) after this long: one warning saying why
    stale_age_periods: int = 5  # a SAMPLE held this many periods by the host before the write gets no torque


@dataclass
class LoopResult:
    ticks: int = 0
    balancing_ticks: int = 0
    end: str = "duration"  # duration | experiment (its plan ran to the end) | trip | operator_stop | error
    trip_reason: str = ""
    trip_message: str = ""
    final_state: str = "idle"
    host_span_s: float = 0.0
    device_span_s: float = 0.0
    overruns: int = 0  # commanded ticks that missed their deadline (one per host stall)
    skipped_periods: int = 0  # stale samples that got no command
    late_commands: int = 0  # device COMMAND_LATE flags while balancing
    device_overruns: int = 0  # samples flagged TICK_OVERRUN: the device itself was late
    device_skipped_periods: int = 0  # periods the device's clock passed without a SAMPLE or a seq gap (its overruns)
    seq_gaps: int = 0
    crc_errors: int = 0
    device_link: dict[str, int] = field(default_factory=dict)  # the device's own link counters (its last STATUS)
    dropped_log_messages: int = 0
    period_us: Histogram = field(default_factory=Histogram)
    jitter_us: Histogram = field(default_factory=Histogram)
    read_us: Histogram = field(default_factory=Histogram)
    update_us: Histogram = field(default_factory=Histogram)
    write_us: Histogram = field(default_factory=Histogram)
    latency_us: Histogram = field(default_factory=Histogram)
    lateness_us: Histogram = field(default_factory=Histogram)
    theta: RunningStats = field(default_factory=RunningStats)
    phi: RunningStats = field(default_factory=RunningStats)
    u: RunningStats = field(default_factory=RunningStats)
    u_comp: RunningStats = field(default_factory=RunningStats)
    trace: RecentTrace = field(default_factory=RecentTrace)  # t, θ, φ of the last minute of balancing (summary)
    events: list[tuple[int, str, str]] = field(default_factory=list)  # (wall ns, level, message)
    swing_up_ticks: int = 0  # ticks the swing-up drove the actuator
    open_loop_ticks: int = 0  # ticks a hanging experiment's plan drove the actuator
    catches: int = 0  # swinging_up → balancing
    falls: int = 0  # balancing → swinging_up
    first_catch_s: float = math.nan  # device time from the start of the swing-up to its first catch
    first_catch_run_s: float = math.nan  # device time from the run's first tick to the first catch
    calibration: StartupCalibration | None = None
    loop_cpu_s: float = 0.0  # CPU time of the loop's thread over the run (not wall time: what a tick costs the machine)
    process_cpu_s: float = 0.0  # ... and of the whole control process (its queue feeder and watcher threads too)

    @property
    def rate_hz(self) -> float:
        return (self.ticks - 1) / self.host_span_s if self.ticks > 1 and self.host_span_s > 0 else math.nan

    @property
    def device_rate_hz(self) -> float:
        return (self.ticks - 1) / self.device_span_s if self.ticks > 1 and self.device_span_s > 0 else math.nan


class ControlLoop:
    """Runs ticks until the duration is reached, a trip, or ``request_stop`` (signal-safe)."""

    def __init__(
        self,
        hw: HardwareInterface,
        controller: Controller,
        supervisor: Supervisor,
        settings: LoopSettings,
        *,
        full_scale: float,
        theta_dot_offset_counts: int = 0,
        calibration: Any,
        log: Sink | None = None,
        dashboard: Sink | None = None,
        on_event: Callable[[str, str], None] | None = None,
        mode: str = "none",
        swing_up: SwingUpConfig | None = None,
    ) -> None:
        self.hw = hw
        self.ctrl = controller
        self.sup = supervisor
        self.settings = settings
        self.full_scale = full_scale
        self.tdo = theta_dot_offset_counts
        self.cal = calibration
        self.log = log
        self.dashboard = dashboard
        self.on_event = on_event
        self.mode = mode
        self.calibration_window = CalibrationWindow(swing_up, settings.rate_hz) if swing_up is not None else None
        self.result = LoopResult()
        self._shown_events: list[str] = []  # events for the dashboard (the ones not printed above it already)
        self._stop: str | None = None
        self._batch: list[tuple] = []
        self._wall0 = time.time_ns()
        self._perf0 = time.perf_counter_ns()
        self._n_sup_transitions = 0
        self._last_seq = 0
        self._stop_error: str | None = None
        self._port_gone = False

    # ----------------------------------------------------------------- control
    def request_stop(self, reason: str) -> None:
        """Ask the loop to stop at its next wake-up (safe from a signal handler)."""
        if self._stop is None:
            self._stop = reason

    def _signal(self, signum: int, _frame: object) -> None:
        self.request_stop(signal.Signals(signum).name)

    def _zero(self) -> None:
        """Zero the actuator now (``hw.stop``: u = 0 the device accepts, then STOP). Never raises."""
        try:
            self._stop_error = self.hw.stop()
        except Exception as err:  # a HardwareInterface must not raise here; still zero first, report after
            self._stop_error = f"{type(err).__name__}: {err}"

    # ----------------------------------------------------------------- outputs
    def _wall(self, perf_ns: int) -> int:
        return self._wall0 + (perf_ns - self._perf0)

    def event(self, level: str, message: str, perf_ns: int | None = None, *, show: bool = True) -> None:
        """Record a supervisor/fault/warning event: logged (after the pending ticks) and shown (unless ``show``
        is False: already said)."""
        wall = self._wall(time.perf_counter_ns() if perf_ns is None else perf_ns)
        self.result.events.append((wall, level, message))
        if show:  # the dashboard's event list: what was not already said above it
            self._shown_events.append(message)
        self._flush_batch()
        if self.log is not None:
            try:
                self.log.put_nowait(("event", (wall, level, message)))
            except queue.Full:
                self.result.dropped_log_messages += 1
        if self.on_event is not None and show:
            self.on_event(level, message)

    def _flush_batch(self) -> None:
        batch = self._batch
        if not batch:
            return
        self._batch = []
        if self.log is None:
            return
        try:
            self.log.put_nowait(("ticks", batch))
        except queue.Full:
            self.result.dropped_log_messages += len(batch)

    def _transitions(self, perf_ns: int | None = None) -> None:
        """Log the supervisor's new transitions; those decided on a tick carry that SAMPLE's arrival (``perf_ns``),
        so an event and the tick it reports sit together on the log's time line however late the loop ran."""
        tr = self.sup.transitions
        while self._n_sup_transitions < len(tr):
            t = tr[self._n_sup_transitions]
            self._n_sup_transitions += 1
            level = "ERROR" if t.new is State.TRIPPED and t.reason != TripReason.OPERATOR_STOP else "INFO"
            self.event(level, f"{t.old.label} → {t.new.label}: {t.message} (seq {t.seq})", perf_ns)

    def _snapshot(self, now_ns: int, state: int, theta: float, phi: float, u: float, u_comp: float,
                  win_ticks: int, win_start: int, win_max_dev: float, fc_hat: float = 0.0) -> None:
        r = self.result
        span = (now_ns - win_start) * 1e-9
        snap = {
            "elapsed": (now_ns - self._perf0) * 1e-9, "state": STATE_NAMES[state], "mode": self.mode,
            "theta": theta, "phi": phi, "u": u, "u_comp": u_comp, "fc_hat": fc_hat,
            "rate_hz": win_ticks / span if span > 0 else 0.0, "jitter_max_us": win_max_dev,
            "overruns": r.overruns, "late_commands": r.late_commands, "seq_gaps": r.seq_gaps,
            "crc_errors": self.hw.crc_errors, "dropped": r.dropped_log_messages, "ticks": r.ticks,
            "trip": self.sup.reason, "events": self._shown_events[-4:],
        }
        with contextlib.suppress(queue.Full):  # the dashboard is behind: skip this snapshot
            self.dashboard.put_nowait(snap)  # type: ignore[union-attr]

    # ----------------------------------------------------------------- the loop
    def run(self) -> LoopResult:
        old = stop_signals.install(self._signal)  # Ctrl-C, Ctrl-\, kill, a closed terminal: an operator stop
        cpu0, process0 = time.thread_time(), time.process_time()
        try:
            self._run()
        except LinkLost as err:
            self._port_gone = err.gone
            self._zero()
            if self._stop is not None:  # Ctrl-C reached the whole group: hil-mock closed its pty first
                self._operator_stop()
            else:
                self._end_link_loss(str(err))
        except BaseException as err:
            self._zero()
            self.sup.trip(self._last_seq, TripReason.ERROR, f"{type(err).__name__}: {err}")
            self.result.end = "error"
            self._transitions()
            raise
        finally:
            self._zero()  # u = 0 and STOP on every path (a no-op if done; tries again if it failed)
            self.result.loop_cpu_s = time.thread_time() - cpu0
            self.result.process_cpu_s = time.process_time() - process0
            if self._stop_error is not None and self._port_gone:  # the trip message already says why
                self.event("WARNING", "u = 0 and STOP not sent (the port is gone): the device zeroes its "
                           "actuator on the hang-up or by its watchdog")
            elif self._stop_error is not None:
                self.event("ERROR", f"could not send u = 0 and STOP to the device ({self._stop_error}); "
                           "its watchdog or the hang-up has to zero the actuator")
            stop_signals.restore(old)
            r = self.result
            r.final_state = self.sup.state.label
            r.trip_reason = self.sup.reason
            if self.sup.tripped:
                r.trip_message = self.sup.transitions[-1].message
            r.crc_errors = self.hw.crc_errors
            r.device_link = {k.removeprefix("device_"): v for k, v in self.hw.counters().items()
                             if k.startswith("device_")}
            self._flush_batch()
        return self.result

    def _operator_stop(self) -> None:
        self.sup.trip(self._last_seq, TripReason.OPERATOR_STOP, f"operator stop ({self._stop})")
        self.result.end = "operator_stop"
        self._transitions()

    def _end_link_loss(self, message: str) -> None:
        self.sup.trip(self._last_seq, TripReason.LINK_LOSS, message)
        self.result.end = "trip"
        self._transitions()

    def _calibrated(self, seq: int, window: CalibrationWindow) -> tuple[StartupCalibration | None, State, bool]:
        """The calibration window is full: take it (logged as metadata; swing up) or refuse it (trip)."""
        got = window.result()
        if isinstance(got, str):
            self.sup.trip(seq, TripReason.CALIBRATION, got)
            return None, State.TRIPPED, False
        self.result.calibration = got
        if self.log is not None:
            try:
                self.log.put_nowait(("metadata", CALIBRATION_METADATA, got.metadata()))
            except queue.Full:
                self.result.dropped_log_messages += 1
        state, reset = self.sup.calibrated(seq, got.describe())
        return got, state, reset

    def _run(self) -> None:
        st = self.settings
        hw, ctrl, sup, r = self.hw, self.ctrl, self.sup, self.result
        comp = ctrl.compensator
        cal, tdo = self.cal, self.tdo
        nominal_us = 1e6 / st.rate_hz
        skip_us = 1.5 * nominal_us  # a SAMPLE this long after the previous one: periods without a SAMPLE before it
        stale_age_ns = round(st.stale_age_periods * 1e9 / st.rate_hz)
        loss_timeout = st.link_timeout_s
        # the duration is device time (its SAMPLE clock), not a tick count: a device streaming faster or slower
        # than its rate, or dropping SAMPLEs, still runs as long as asked; the last tick is one period short of it
        last_tick_us = None if st.duration is None else st.duration * 1e6 - nominal_us
        stats_after = round(st.stats_after_s * st.rate_hz)
        idle_notice = round(st.idle_notice_s * st.rate_hz)  # ticks: say once why it does not arm
        clock = DeviceClock()
        perf = time.perf_counter_ns
        batch_ticks = st.batch_ticks
        snap_ticks = st.snapshot_ticks if self.dashboard is not None else 0
        log_on = self.log is not None
        full_scale = self.full_scale
        wall_off = self._wall0 - self._perf0  # a host perf_counter_ns on the wall clock (``_wall``)
        hists = (r.period_us, r.jitter_us, r.read_us, r.update_us, r.write_us, r.latency_us, r.lateness_us)
        h_period, h_jit, h_read, h_upd, h_wr, h_lat, h_late = (h.pending.append for h in hists)  # binned by fold
        fold_in = batch_ticks
        prev_start = 0
        prev_seq = -1
        prev_balancing = False
        wrote_prev = False
        skipped = ended_run = 0
        first_dev_us = first_t1 = prev_dev_us = 0
        balance_start = -1
        win_ticks, win_start, win_max = 0, perf(), 0.0
        timeout = st.first_sample_timeout
        window = self.calibration_window
        startup: StartupCalibration | None = None
        swing_start_us = 0
        excitation = ctrl.excitation  # a designed experiment: its segments are logged as events, its end ends the run
        while True:
            t0 = perf()
            s = hw.read(timeout)
            t1 = perf()
            if s is not None:
                self._last_seq = s.seq
            if self._stop is not None:
                self._zero()
                self._operator_stop()
                return
            if s is None:
                waited = (t1 - t0) * 1e-9
                self._zero()
                what = (f"no SAMPLE for {waited * 1e3:.1f} ms (limit {timeout * 1e3:.1f} ms) after seq {self._last_seq}"
                        if r.ticks else f"the device sent no SAMPLE in {waited * 1e3:.1f} ms (limit "
                        f"{timeout * 1e3:.1f} ms) after the handshake")
                self._end_link_loss(f"link loss: {what}")
                return
            timeout = loss_timeout
            seq = s.seq
            arrival = hw.arrival_ns
            seen = arrival or t1  # the SAMPLE's host time (a device that does not stamp arrivals: the read's end)
            read_us = (t1 - arrival if arrival >= t0 else t1 - t0) * 1e-3
            dev_us = clock.unwrap(s.t_us)
            est_ns = clock.observe(dev_us, arrival)
            n = r.ticks
            if n == 0:
                first_dev_us = dev_us
                period_us = nominal_us
            else:
                period_us = (t1 - prev_start) * 1e-3
                gap = (seq - prev_seq - 1) & 0xFFFFFFFF
                if gap >= 0x80000000:  # seq repeated or went back: not this session's stream any more
                    self._zero()
                    sup.trip(seq, TripReason.SEQUENCE, f"SAMPLE seq went from {prev_seq} to {seq}: the device "
                             "restarted without a handshake")
                    r.end = "trip"
                    self._transitions()
                    return
                r.seq_gaps += gap
                if dev_us - prev_dev_us > skip_us:  # more than one period passed: lost SAMPLEs or the device's own skip
                    missed = round((dev_us - prev_dev_us) / nominal_us) - 1 - gap
                    if missed > 0:  # an overrunning device skips its timer periods without a SAMPLE (seq not skipped)
                        r.device_skipped_periods += missed
                if dev_us < prev_dev_us:  # the same session's clock went back: its times (and dt) cannot be used
                    self._zero()
                    sup.trip(seq, TripReason.SEQUENCE, f"the device clock went back from {prev_dev_us} µs to {dev_us} µs "
                             f"at seq {seq}: its timestamps cannot be trusted (a device fault)")
                    r.end = "trip"
                    self._transitions()
                    return
            prev_dev_us = dev_us
            prev_start = t1
            prev_seq = seq
            stale = hw.pending > 0
            status = s.status
            if prev_balancing and status & _COMMAND_LATE:
                r.late_commands += 1
            if status & _TICK_OVERRUN:
                r.device_overruns += 1
            if stale:  # a newer sample is waiting: this period is skipped (no command)
                r.skipped_periods += 1
                skipped += 1
                late: bool | None = None
            else:  # an overrun: periods were skipped before it, or the device got our last command late
                late = skipped > 0 or (wrote_prev and status & _COMMAND_LATE != 0)
                if late:
                    r.overruns += 1
                ended_run, skipped = skipped, 0
            theta_dev, theta_dot, phi_dev = cal.to_si(s.theta_adc, s.theta_dot_adc - tdo, s.phi_count)
            if startup is None:
                theta, phi = theta_dev, phi_dev
            else:
                theta, phi = startup.apply(theta_dev, phi_dev)
            state, reset = sup.step(seq, theta, phi, status, late)
            if state is _CALIBRATING and window is not None and window.add(theta, phi):
                startup, state, reset = self._calibrated(seq, window)
                if startup is not None:
                    theta, phi = startup.apply(theta_dev, phi_dev)
                    swing_start_us = dev_us
            if reset:
                ctrl.reset(phi)
            t2 = perf()
            m = Measurement(dev_us * 1e-6, theta, theta_dot, phi)
            if state is _BALANCING or state is _SWINGING or state is _OPEN_LOOP:
                out = ctrl.update(m)
                if window is not None:
                    was = state
                    state = sup.follow(seq, out.swinging, theta)
                    if state is not was:
                        if state is _BALANCING:
                            r.catches += 1
                            if r.catches == 1:
                                r.first_catch_s = (dev_us - swing_start_us) * 1e-6
                                r.first_catch_run_s = (dev_us - first_dev_us) * 1e-6
                        else:
                            r.falls += 1
                u = out.u
                if u - u != 0.0:  # NaN or inf: tripped, the write below answers this SAMPLE with u = 0
                    sup.command_not_finite(seq, u)
                    state = _TRIPPED
                    u = u_lin = u_comp = 0.0
                    sat = False
                    phd = out.phi_dot_hat
                else:
                    u_lin, u_comp, phd, sat = out.u_lin, out.u_comp, out.phi_dot_hat, out.saturated
            else:
                phd = ctrl.hold(m)
                u = u_lin = u_comp = 0.0
                sat = False
            t3 = perf()
            acting = state is _BALANCING or state is _SWINGING or state is _OPEN_LOOP  # the actuator is ours this period
            if not stale and acting and t3 - seen > stale_age_ns:
                # the SAMPLE aged periods in the host (the process was stopped or starved between read and write): a
                # torque computed from it is not sent; the period counts as skipped like a stale one. (Its age since
                # the device's tick would not do: a mock paced in lockstep keeps no real-time clock.)
                stale = True
                r.skipped_periods += 1
                if late and ended_run:  # it did not end the run of skipped periods after all: still one overrun
                    r.overruns -= 1
                skipped = ended_run + 1
            if state is _TRIPPED or not stale:
                if acting:
                    c = round(u / full_scale * COMMAND_FULL_SCALE)  # u in COMMAND counts, clipped to full scale
                    hw.write(seq, COMMAND_FULL_SCALE if c > COMMAND_FULL_SCALE else max(c, -COMMAND_FULL_SCALE), _ENABLE)
                else:  # zero; clear a latched fault while waiting to arm
                    hw.write(seq, 0, _CLEAR_FAULT if (status & _FAULT_MASK and state is State.IDLE) else 0)
                t4 = perf()
                latency_us = (t4 - est_ns) * 1e-3
                h_lat(latency_us)
            else:
                t4 = t3
                latency_us = -1.0
            prev_balancing = acting  # the actuator was ours
            wrote_prev = not stale
            # ---- accounting (after the command is out)
            update_us = (t3 - t2) * 1e-3
            write_us = (t4 - t3) * 1e-3
            lateness_us = (t1 - est_ns) * 1e-3
            dev = period_us - nominal_us
            if dev < 0:
                dev = -dev
            if n:
                h_period(period_us)
                h_jit(dev)
            h_read(read_us)
            h_upd(update_us)
            h_wr(write_us)
            h_late(lateness_us)
            fold_in -= 1
            if not fold_in:
                fold_in = batch_ticks
                for h in hists:
                    h.fold()
            r.ticks = n + 1
            if n == 0:
                first_t1 = t1
            r.host_span_s = (t1 - first_t1) * 1e-9
            r.device_span_s = (dev_us - first_dev_us) * 1e-6
            if state is _SWINGING:
                r.swing_up_ticks += 1
            elif state is _OPEN_LOOP:
                r.open_loop_ticks += 1
            elif state is _BALANCING:
                r.balancing_ticks += 1
                if balance_start < 0:
                    balance_start = n
                if n - balance_start >= stats_after:
                    r.theta.add(theta)
                    r.phi.add(phi)
                    r.u.add(u)
                    r.u_comp.add(u_comp)
                    r.trace.add(m.t, theta, phi)
            if log_on:
                self._batch.append((
                    wall_off + seen, dev_us * 1000, seq, dev_us * 1e-6,
                    s.theta_adc, s.theta_dot_adc, s.phi_count, status,
                    theta_dev, theta_dot, phi_dev, phd, u, u_lin, u_comp, sat, int(state), reset,
                    period_us, read_us, update_us, write_us, latency_us, lateness_us,
                    r.overruns, r.seq_gaps, hw.crc_errors, r.dropped_log_messages, comp.coulomb_level,
                ))
                if len(self._batch) >= batch_ticks:
                    self._flush_batch()
            if len(sup.transitions) != self._n_sup_transitions:
                self._transitions(seen)
            if excitation is not None and excitation.message is not None:
                self.event("INFO", excitation.take_message(), seen)  # type: ignore[arg-type]
            elif n == idle_notice and state is State.IDLE and not sup.transitions:
                self.event("WARNING", f"not armed after {st.idle_notice_s:g} s: {sup.why_not_armed(theta, phi, status)}")
            if snap_ticks:
                win_ticks += 1
                if dev > win_max:
                    win_max = dev
                if win_ticks >= snap_ticks:
                    self._snapshot(t4, int(state), theta, phi, u, u_comp, win_ticks, win_start, win_max,
                                   comp.coulomb_level)
                    win_ticks, win_start, win_max = 0, t4, 0.0
            if state is _TRIPPED:
                r.end = "trip"
                return
            if last_tick_us is not None and dev_us - first_dev_us >= last_tick_us:
                r.end = "duration"
                return
            if excitation is not None and excitation.done:
                r.end = "experiment"
                return
