"""The DAQ firmware's logic without wall-clock time or I/O: bytes in, frames out, one ``tick`` per
timer period. hil_mock.device drives it in real time over a pseudo-terminal.

Behind it is the core simulator (furuta_rt.sim.simulator.Simulator, its plant integrated in C by
furuta_rt.sim.compiled where that covers the model); there is no physics here. The
order of operations per tick is the one of furuta_rt.sim.closed_loop.run_closed_loop, so a run
against the mock with seed s reproduces the simulation with seed s, up to the COMMAND's 16-bit
quantisation:

    tick k (device time k·T):
      1. latch ADCs and encoder: sim.sample()                        (t_us = device clock)
      2. newest accepted COMMAND received since tick k−1 → output     (else hold, COMMAND_LATE)
      3. watchdog and ADC over-range checks; a latched fault gives zero output
      4. SAMPLE k written
      5. sim.set_command(output); plant advanced to (k+1)·T

The rules are those of firmware_protocol/PROTOCOL.md §5–7. Where the spec leaves a choice:

* The plant is held at its initial state until the first accepted HELLO, then runs in device time
  for good: STOP, a hang-up or a reset leave it unactuated (the pendulum falls) and do not rewind
  the clock. A HELLO to an idle device (a new host session) puts the rig back at its initial state
  (``initial_theta``, at rest, arm at 0, the noise seed from the start), as the operator of a real rig
  lifts the pendulum before starting a run: without that, every host after the first found it hanging
  with θ's ADC at its rail (ADC_OVERRANGE) and never armed. A HELLO while streaming (the host's retry,
  a second host) does not touch the plant.
* "Arrival" of a COMMAND (watchdog) is quantised to the tick that reads it. The watchdog trips at
  the first tick at least ``watchdog_ms`` after the last accepted COMMAND (or the HELLO).
* The HELLO_ACK is preceded by one 0x00 (§2.1: flush the peer's partial frame).
* STATUS counters (crc_errors, frame_errors, frames_rx, uart_overruns, uart_line_errors) count from the last
  accepted HELLO. The pseudo-terminal has no UART: its error counts are what ``set_uart_errors`` says (0 unless a
  test or fault sets them), and a reset starts them from 0.
* ``reboot(cause)`` is a reset for ``cause`` (the reset pin by default), which the next HELLO_ACK reports.
* CONFIG accepts 1 ≤ rate_hz ≤ min(10 000, physics substep rate) and watchdog_ms ≥ 1.
"""

from __future__ import annotations

import dataclasses
import struct

from firmware_protocol import (
    COMMAND_FULL_SCALE,
    PROTOCOL_VERSION,
    SCHEMA_HASH,
    ActuatorKind,
    Command,
    CommandFlags,
    Config,
    Hello,
    HelloAck,
    ResetCause,
    Sample,
    Status,
    StatusFlags,
    Stop,
    StreamDecoder,
    command_accepted,
    counts_to_actuator,
    encode,
)
from furuta_rt.config import RigConfig
from furuta_rt.model.friction import Coulomb, CoulombStiction
from furuta_rt.model.rig import RigModel
from furuta_rt.sim.compiled import make_simulator
from furuta_rt.sim.simulator import Simulator
from hil_mock.config import MAX_RATE_HZ, DeviceSettings

FW_VERSION = (0, 1, 0)
STATUS_PERIOD_NS = 1_000_000_000
_MASK32 = 0xFFFFFFFF

_WATCHDOG = int(StatusFlags.WATCHDOG_TRIPPED)
_OVERRANGE = int(StatusFlags.ADC_OVERRANGE)
_CRC = int(StatusFlags.CRC_ERROR)
_ENABLED = int(StatusFlags.ENABLED)
_LATE = int(StatusFlags.COMMAND_LATE)
_OVERRUN = int(StatusFlags.TICK_OVERRUN)
_CONFIG_REJECTED = int(StatusFlags.CONFIG_REJECTED)
_TX_OVERFLOW = int(StatusFlags.TX_OVERFLOW)
_ENABLE = int(CommandFlags.ENABLE)
_CLEAR = int(CommandFlags.CLEAR_FAULT)


def _f32(x: float) -> float:
    """``x`` rounded to IEEE binary32, as the device sends it."""
    return struct.unpack("<f", struct.pack("<f", x))[0]


def _protocol_latency(model: RigModel, rate_hz: float) -> RigModel:
    """The model with its ``command_latency`` (total, from the sample instant) turned into the actuator delay on top
    of the protocol's one period (a COMMAND answering SAMPLE k is applied at tick k+1)."""
    L = model.command_latency
    if L is None:
        return model
    extra = L - 1.0 / rate_hz
    if extra < -1e-12:
        raise ValueError(f"command_latency {L:g} s is shorter than the protocol's one period ({1.0 / rate_hz:g} s at "
                         f"{rate_hz:g} Hz): the mock applies a COMMAND at the tick after its SAMPLE; simulate it with "
                         "run_closed_loop instead")
    actuator = dataclasses.replace(model.actuator, delay=max(extra, 0.0))
    return dataclasses.replace(model, actuator=actuator, command_latency=None)


class Firmware:
    """Protocol state machine of the DAQ with the simulated rig behind it."""

    def __init__(self, rig: RigConfig, model: RigModel, settings: DeviceSettings, rate_hz: int) -> None:
        top = min(MAX_RATE_HZ, settings.substep_hz)
        if not 1 <= rate_hz <= top:
            raise ValueError(f"rate {rate_hz} Hz: must be within 1..{top:g} Hz (at most the physics substep rate)")
        self.rig = rig
        model = _protocol_latency(model, rate_hz)
        self.model = model
        self.settings = settings
        self.substep_hz = settings.substep_hz
        # One simulator "tick" is one physics substep, so every device rate maps onto the same substep grid;
        # with substep_hz a multiple of the rate this is step for step Simulator(model, rate, substep_hz).
        self.sim = self._new_plant()
        self.full_scale = _f32(rig.actuator.limit)
        self.actuator_kind = ActuatorKind.TORQUE_NM if rig.actuator.kind == "torque" else ActuatorKind.VOLTAGE_V
        self.default_rate_hz = rate_hz
        self.decoder = StreamDecoder()
        self.tx: list[bytes] = []
        self.clock_ns = 0  # device clock since boot
        self.plant_start_ns: int | None = None
        self.substeps_done = 0
        self.output = 0.0
        self.faults = 0
        self.commands_rx = 0
        self.commands_applied = 0
        self.commands_discarded = 0
        self.commands_other_session = 0
        self.reset_cause = ResetCause.POWER_ON
        self.uart_overruns = 0  # the receiver's error counts since the last reset (set_uart_errors)
        self.uart_line_errors = 0
        self.watchdog_trips = 0
        self.handshakes = 0
        self.handshakes_refused = 0
        self.samples_sent = 0
        self.status_sent = 0
        self.reboots = 0
        self.hangups = 0
        self.replacements = 0  # new sessions that found the rig put back at its initial state
        self._reconfigured = False  # a HELLO or CONFIG arrived since the last tick
        self._boot()

    # ----------------------------------------------------------------- state
    def _new_plant(self) -> Simulator:
        """The rig at its initial state, at rest."""
        s = self.settings
        return make_simulator(self.model, rate_hz=self.substep_hz, substep_hz=self.substep_hz, seed=s.seed,
                              x0=(s.initial_theta, 0.0, 0.0, 0.0), compiled=s.plant == "compiled")

    def _boot(self) -> None:
        """Power-up state: default configuration, idle, output zero, no fault."""
        self.rate_hz = self.default_rate_hz
        self.period_ns = round(1e9 / self.rate_hz)
        self.watchdog_ms = self.settings.watchdog_ms
        self.faults = 0
        self.sticky = 0  # CRC_ERROR / TICK_OVERRUN / TX_OVERFLOW since the previous SAMPLE
        self.config_rejected = False
        self.seq = 0  # seq of the next SAMPLE (unbounded; sent modulo 2**32)
        self._rx_errors_seen = self.decoder.errors
        self._base = (0, 0, 0)  # decoder (crc, other errors, frames ok) at the last HELLO
        self._uart_base = (self.uart_overruns, self.uart_line_errors)
        self.session = 0  # the nonce of the HELLO that started the session (meaningful while streaming)
        self._last_cmd_ns = 0
        self._next_status_ns = 0
        self._go_idle()

    def _go_idle(self) -> None:
        self.streaming = False
        self.enabled = False
        self._held: tuple[int, int, int] | None = None  # applied COMMAND (seq, counts, flags) being held
        self._new: tuple[int, int, int] | None = None  # newest accepted COMMAND not yet applied
        self._last_applied: int | None = None
        self._answered = False
        self.last_cmd_seq = 0
        self._set_output(0.0)

    def _set_output(self, u: float) -> None:
        if u != self.output:
            self.output = u
            self.sim.set_command(u)

    def reboot(self, cause: ResetCause = ResetCause.PIN) -> None:
        """Device reset for ``cause``: power-up state, idle until a HELLO, SAMPLE seq from 0. The plant runs on."""
        self.decoder.reset()
        self.tx.clear()
        self.reboots += 1
        self.reset_cause = cause
        self.uart_overruns = self.uart_line_errors = 0
        self._boot()

    def set_uart_errors(self, overruns: int, line_errors: int) -> None:
        """The receiver's error counts since the last reset, as a UART counts them (free-running, mod 2³²)."""
        self.uart_overruns, self.uart_line_errors = overruns, line_errors

    def hangup(self) -> None:
        """The host closed the port (DTR drop): output zero, idle. Latched faults are kept."""
        if self.streaming:
            self.hangups += 1
        self._go_idle()
        self.decoder.reset()

    @property
    def status_flags(self) -> int:
        flags = self.faults | self.sticky | (_ENABLED if self.enabled else 0)
        return flags | (_CONFIG_REJECTED if self.config_rejected else 0)

    @property
    def armed(self) -> bool:
        """Streaming and the host has sent at least one accepted COMMAND in this session."""
        return self.streaming and self._last_applied is not None

    @property
    def answered(self) -> bool:
        """A COMMAND answering the last SAMPLE sent has been accepted."""
        return self._answered

    @property
    def reconfigured(self) -> bool:
        """A HELLO or a CONFIG arrived since the last tick: a host that (re)configures the session does not answer a
        SAMPLE sent before it (it drops the SAMPLE that shares a read with the HELLO_ACK or the STATUS), so a lockstep
        device waits no longer for that answer (the answer missing: COMMAND_LATE at the next tick, as a wait in vain)."""
        return self._reconfigured

    @property
    def plant_time(self) -> float:
        """Simulated seconds since the plant was released (first HELLO)."""
        return self.substeps_done / self.substep_hz

    # ----------------------------------------------------------------- input
    def receive(self, data: bytes) -> None:
        """Bytes from the host, any chunking. Messages act at once; COMMANDs are applied at the next tick."""
        msgs = self.decoder.feed(data)
        for i, msg in enumerate(msgs):
            t = type(msg)
            if t is Command:
                self._on_command(msg)  # type: ignore[arg-type]
            elif t is Hello:
                self._reconfigured = True
                self._on_hello(msg, later_frames=len(msgs) - i - 1)  # type: ignore[arg-type]
            elif t is Config:
                self._reconfigured = True
                self._on_config(msg)  # type: ignore[arg-type]
            elif t is Stop:
                self._on_stop()
            # device → host types arriving here (a loopback, a confused host) are ignored

    def _on_command(self, msg: Command) -> None:
        """§6: accepted iff not newer than the last SAMPLE sent and newer than the last applied/accepted."""
        self.commands_rx += 1
        if self.streaming and msg.session != self.session:  # another session's (delayed, a second host's)
            self.commands_discarded += 1
            self.commands_other_session += 1
            return
        last_sent = (self.seq - 1) & _MASK32 if self.seq else None
        ref = self._new[0] if self._new is not None else self._last_applied
        if not self.streaming or not command_accepted(msg.seq, last_sent, ref):
            self.commands_discarded += 1
            return
        self._new = (msg.seq, msg.command, msg.flags)
        if msg.seq == last_sent:
            self._answered = True

    def _on_stop(self) -> None:
        """§4 STOP: output zero at once, idle until a new HELLO."""
        self._go_idle()

    def _on_hello(self, msg: Hello, later_frames: int = 0) -> None:
        self.tx.append(b"\x00" + encode(self.hello_ack(msg.nonce)))
        if msg.protocol_version != PROTOCOL_VERSION or msg.schema_hash != SCHEMA_HASH:
            self.handshakes_refused += 1
            self._go_idle()  # never stream or drive the actuator for a host built against other definitions
            return
        self.handshakes += 1
        if self.plant_start_ns is None:
            self.plant_start_ns = self.clock_ns
        elif not self.streaming:  # a new host session: the rig is put back at its initial state
            self.sim = self._new_plant()
            self.replacements += 1
        self._go_idle()  # restart the session: output zero, faults kept
        self.streaming = True
        self.session = msg.nonce  # from now on a COMMAND of an earlier session is discarded
        self.seq = 0
        self.sticky = 0
        self._last_cmd_ns = self.clock_ns  # watchdog armed by the handshake (§5)
        self._next_status_ns = self.clock_ns + STATUS_PERIOD_NS
        d = self.decoder
        self._base = (d.crc_errors, d.errors - d.crc_errors, d.frames_ok - later_frames)
        self._rx_errors_seen = d.errors
        self._uart_base = (self.uart_overruns, self.uart_line_errors)

    def hello_ack(self, nonce: int) -> HelloAck:
        """The device's identity: always its own version and schema hash, whatever the HELLO carried."""
        cal = self.model.calibration
        return HelloAck(
            protocol_version=PROTOCOL_VERSION,
            schema_hash=SCHEMA_HASH,
            nonce=nonce,
            device_id=self.settings.device_id,
            fw_major=FW_VERSION[0],
            fw_minor=FW_VERSION[1],
            fw_patch=FW_VERSION[2],
            sample_rate_hz=self.rate_hz,
            watchdog_ms=self.watchdog_ms,
            theta_rad_per_count=cal.theta_rad_per_count,
            theta_offset_counts=cal.theta_offset_counts,
            theta_dot_rad_s_per_count=cal.theta_dot_rad_s_per_count,
            theta_dot_offset_counts=0,
            phi_counts_per_rev=cal.phi_counts_per_rev,
            actuator_full_scale=self.full_scale,
            actuator_kind=int(self.actuator_kind),
            reset_cause=int(self.reset_cause),
        )

    def _on_config(self, msg: Config) -> None:
        """§4 CONFIG: apply (output zero, ENABLE needed again, seq continues) or reject; answer with STATUS."""
        if 1 <= msg.rate_hz <= min(MAX_RATE_HZ, self.substep_hz) and msg.watchdog_ms >= 1:
            self.config_rejected = False
            self.rate_hz = msg.rate_hz
            self.period_ns = round(1e9 / msg.rate_hz)
            self.watchdog_ms = msg.watchdog_ms
            self._held = self._new = None
            self.enabled = False
            self._set_output(0.0)
        else:
            self.config_rejected = True
        self._send_status()

    # ----------------------------------------------------------------- output
    def status(self) -> Status:
        d = self.decoder
        crc0, other0, ok0 = self._base
        return Status(
            flags=self.status_flags,
            rate_hz=self.rate_hz,
            watchdog_ms=self.watchdog_ms,
            crc_errors=(d.crc_errors - crc0) & _MASK32,
            frame_errors=(d.errors - d.crc_errors - other0) & _MASK32,
            frames_rx=(d.frames_ok - ok0) & _MASK32,
            last_cmd_seq=self.last_cmd_seq & _MASK32,
            uart_overruns=(self.uart_overruns - self._uart_base[0]) & _MASK32,
            uart_line_errors=(self.uart_line_errors - self._uart_base[1]) & _MASK32,
        )

    def _send_status(self) -> None:
        self.tx.append(encode(self.status()))
        self.status_sent += 1

    def note_tx_overflow(self) -> None:
        """The transport dropped an outgoing frame: reported as TX_OVERFLOW in the next SAMPLE."""
        self.sticky |= _TX_OVERFLOW

    # ----------------------------------------------------------------- time
    def advance_plant(self) -> None:
        """Run the plant up to the device clock with the current output."""
        if self.plant_start_ns is None:
            return
        target = round((self.clock_ns - self.plant_start_ns) * self.substep_hz * 1e-9)
        n = target - self.substeps_done
        if n > 0:
            self.sim.advance(n)
            self.substeps_done = target

    def set_arm_coulomb(self, fc: float, fs: float | None = None) -> None:
        """The arm's Coulomb level becomes ``fc`` (breakaway ``fs``, default: the present one, at least fc) from
        now on, viscous part unchanged (the friction_step fault); kept across session restarts."""
        arm = self.model.arm_friction
        if arm.lugre is not None:
            raise ValueError("friction_step sets a Coulomb level; this rig's arm friction is LuGre")
        old_fs = arm.dry.stick_limit if isinstance(arm.dry, CoulombStiction) else None
        breakaway = fs if fs is not None else (max(old_fs, fc) if old_fs is not None else None)
        dry = Coulomb(Fc=fc) if breakaway is None else CoulombStiction(Fc=fc, Fs=breakaway)
        friction = dataclasses.replace(arm, dry=dry)
        self.model = dataclasses.replace(self.model, arm_friction=friction)
        self.sim.set_arm_friction(friction)

    def skip(self, periods: int) -> None:
        """The timer fired ``periods`` times without the tick running (overrun, stall): the clock and
        the plant move on with the output held, no SAMPLE is made, seq is not skipped, TICK_OVERRUN."""
        if periods > 0:
            self.clock_ns += periods * self.period_ns
            self.sticky |= _OVERRUN
            self.advance_plant()

    def tick(self, advance: bool = True) -> None:
        """One timer period (see the module docstring for the order of operations). ``advance=False`` leaves
        step 5's plant integration to the caller's ``advance_plant()``, so a device sends the SAMPLE first (as
        the real firmware's DMA does) and the host does not see the simulator's compute time as link delay."""
        self._reconfigured = False
        errors = self.decoder.errors
        if errors != self._rx_errors_seen:
            self._rx_errors_seen = errors
            self.sticky |= _CRC
        if self.streaming:
            self._streaming_tick()
        self.clock_ns += self.period_ns
        if advance:
            self.advance_plant()

    def _streaming_tick(self) -> None:
        now = self.clock_ns
        raw = self.sim.sample()  # 1. acquisition
        new = self._new  # 2. newest accepted COMMAND
        clearing = False
        if new is not None:
            self._new = None
            self._held = new
            self._last_applied = new[0]
            self.last_cmd_seq = new[0]
            self._last_cmd_ns = now
            self.commands_applied += 1
            if new[2] & _CLEAR:
                clearing = True
                cleared = self.faults & ~(_OVERRANGE if raw.overrange else 0)
                if cleared:
                    self.faults &= ~cleared
                    self._send_status()
                self._held = (new[0], 0, 0)  # output zero now; ENABLE takes effect from the next COMMAND
        late = _LATE if (self.seq > 0 and not self._answered) else 0
        self._answered = False
        # 3. faults
        if not self.faults & _WATCHDOG and now - self._last_cmd_ns >= self.watchdog_ms * 1_000_000:
            self.faults |= _WATCHDOG
            self.watchdog_trips += 1
            self._send_status()
        if raw.overrange and not self.faults & _OVERRANGE:
            self.faults |= _OVERRANGE
            self._send_status()
        held = self._held
        self.enabled = held is not None and bool(held[2] & _ENABLE) and not self.faults and not clearing
        # 4. SAMPLE k
        self.tx.append(encode(Sample(
            self.seq & _MASK32, (now // 1000) & _MASK32, raw.theta_adc, raw.theta_dot_adc, raw.phi_count,
            self.status_flags | late,
        )))
        self.sticky = 0
        self.seq += 1
        self.samples_sent += 1
        if now >= self._next_status_ns:
            self._next_status_ns = now + STATUS_PERIOD_NS
            self._send_status()
        # 5. output for the coming period (the caller advances the plant)
        if self.enabled:
            counts = max(held[1], -COMMAND_FULL_SCALE)  # type: ignore[index]  (§4: −32768 acts as −32767)
            self._set_output(counts_to_actuator(counts, self.full_scale))
        else:
            self._set_output(0.0)
