"""The C firmware core (firmware_protocol/firmware) as hil_mock's device logic: ``hil-mock --firmware c``.

``CFirmware`` is a drop-in for hil_mock.firmware.Firmware: the same plant, sensor and actuator models (inherited:
the simulator, its initial state, the rig put back at a new session, the plant advanced in device time), with the
protocol decisions — handshake, CONFIG, command acceptance, watchdog, faults, every byte sent — made by the C
code that runs on the microcontroller, built for the host (firmware_protocol.hostbuild) and called through
ctypes. With the compiled plant (furuta_rt.sim.compiled) the whole tick is C (hil_mock/csrc/device.c): the DAQ's
sensor path, the core's tick, the frames out and the plant's substeps, one call; Python hands it the bytes the
host sent, the simulator's noise draws in blocks and the actuator's shaping as a table of every COMMAND count
(Actuator.torque_terms, the one definition), and writes the frames out. With a plant plant.c does not cover, the
Python simulator is sampled and advanced around the same calls. The C never calls back into Python.

In lockstep the C also serves the common round on the pty itself (``serve_lockstep``: tick, write, plant, wait for
the COMMAND, read it — no Python between a COMMAND's arrival and the next SAMPLE) and hands the loop back to
hil_mock.device wherever Python acts: faults, a new session, the noise block, a new actuator count, the unusual I/O.
"""

from __future__ import annotations

import ctypes
import functools
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from firmware_protocol import HelloAck, ResetCause, Status, counts_to_actuator
from firmware_protocol.hostbuild import HEADERS, SOURCES, host_library
from furuta_rt.config import RigConfig
from furuta_rt.model.actuator import Actuator
from furuta_rt.model.rig import RigModel
from furuta_rt.model.sensors import Calibration
from furuta_rt.sim.compiled import HEADER as PLANT_HEADER
from furuta_rt.sim.compiled import SOURCE as PLANT_SOURCE
from furuta_rt.sim.compiled import CompiledSimulator
from hil_mock.config import MAX_RATE_HZ, DeviceSettings
from hil_mock.firmware import Firmware

DEVICE_SOURCE = Path(__file__).parent / "csrc" / "device.c"
WRAPPING_RAIL = 1 << 20  # beyond every int16 reading
OUT_BYTES = 4096  # device.c HIL_OUT_BYTES
OUT_FRAMES = 128  # device.c HIL_OUT_FRAMES
NOISE_BLOCK = 4096  # noise draws handed to device.c at a time
_STREAMING, _ANSWERED, _NEW_SESSION, _NOISE_LOW, _FRAMES, _NO_NOISE, _SHAPE, _RECONFIGURED = (
    1, 2, 4, 8, 16, 32, 64, 128)  # device.c's
_SLOW = _NEW_SESSION | _NOISE_LOW | _FRAMES | _NO_NOISE | _SHAPE
AT_TOP, AFTER_WRITE, AWAITING = 0, 1, 2  # device.c hil_lockstep's phases
_DP = ctypes.POINTER(ctypes.c_double)
STATE_FIELDS = (
    "clock_ns", "period_ns", "rate_hz", "watchdog_ms", "streaming", "enabled", "answered", "any_applied",
    "output_counts", "faults", "status_flags", "new_sessions", "tx_frames", "commands_rx", "commands_applied",
    "commands_discarded", "watchdog_trips", "handshakes", "handshakes_refused", "samples_sent", "status_sent",
    "hangups", "reboots", "frames_ok", "crc_errors", "errors", "seq", "last_cmd_seq", "commands_other_session",
)  # host_hal.c host_state()
_COUNTERS = ("commands_rx", "commands_applied", "commands_discarded", "watchdog_trips", "handshakes",
             "handshakes_refused", "samples_sent", "status_sent", "hangups", "reboots", "rate_hz", "watchdog_ms",
             "faults", "seq", "last_cmd_seq", "commands_other_session")
_STATUS_FLAGS, _CRC_ERRORS, _ERRORS, _FRAMES_OK = (
    STATE_FIELDS.index(name) for name in ("status_flags", "crc_errors", "errors", "frames_ok"))


class Board(ctypes.Structure):
    """fw_core.h ``fw_board_t``."""

    _fields_ = (
        ("device_id", ctypes.c_uint32),
        ("default_rate_hz", ctypes.c_uint16),
        ("max_rate_hz", ctypes.c_uint16),
        ("default_watchdog_ms", ctypes.c_uint16),
        ("theta_rad_per_count", ctypes.c_float),
        ("theta_offset_counts", ctypes.c_int16),
        ("theta_dot_rad_s_per_count", ctypes.c_float),
        ("theta_dot_offset_counts", ctypes.c_int16),
        ("phi_counts_per_rev", ctypes.c_uint32),
        ("actuator_full_scale", ctypes.c_float),
        ("actuator_kind", ctypes.c_uint8),
        ("theta_adc_min", ctypes.c_int32),
        ("theta_adc_max", ctypes.c_int32),
        ("theta_dot_adc_min", ctypes.c_int32),
        ("theta_dot_adc_max", ctypes.c_int32),
        ("min_rate_hz", ctypes.c_uint16),  # 0: CONFIG's limits are the protocol's (as hil_mock.firmware)
        ("max_watchdog_ms", ctypes.c_uint16),
    )


@functools.cache
def load_library() -> ctypes.CDLL:
    """The host build of the firmware (built and cached on first use) with its signatures declared."""
    return _declare_core(ctypes.CDLL(str(host_library())))


def _declare_core(lib: ctypes.CDLL) -> ctypes.CDLL:
    """The host HAL's functions (firmware/host/host_hal.c) declared on ``lib``."""
    dev = ctypes.c_void_p
    u8, u16, u32, i16, i32 = ctypes.c_uint8, ctypes.c_uint16, ctypes.c_uint32, ctypes.c_int16, ctypes.c_int32
    for name, args, res in (
        ("host_device_size", (), ctypes.c_size_t),
        ("host_board_size", (), ctypes.c_size_t),
        ("host_device_init", (dev, ctypes.POINTER(Board)), None),
        ("host_rx", (dev, ctypes.c_char_p, ctypes.c_size_t), None),
        ("host_tick", (dev, i16, i16, i32, u8), None),
        ("host_skip", (dev, u32), None),
        ("host_reboot", (dev, u8), None),
        ("host_uart_errors", (dev, u32, u32), None),
        ("host_hangup", (dev,), None),
        ("host_note_tx_overflow", (dev,), None),
        ("host_take_tx", (dev, ctypes.c_char_p, ctypes.POINTER(u16)), u32),
        ("host_state", (dev, ctypes.POINTER(ctypes.c_uint64)), None),
        ("host_command_accepted", (u32, u8, u32, u8, u32), u8),
    ):
        fn = getattr(lib, name)
        fn.argtypes = args
        fn.restype = res
    if lib.host_board_size() != ctypes.sizeof(Board):
        raise RuntimeError("firmware/host: fw_board_t and c_firmware.Board differ in size")
    return lib


class HilDevice(ctypes.Structure):
    """hil_mock/csrc/device.c ``hil_device_t``."""

    _fields_ = (
        ("fw", ctypes.c_void_p),
        ("params", ctypes.c_void_p),
        ("state", _DP), ("ring", _DP),
        ("head", ctypes.POINTER(ctypes.c_int32)),
        ("n_delay", ctypes.c_int32),
        ("state0", _DP), ("ring0", _DP), ("actuation", _DP), ("noise", _DP), ("noise0", _DP),
        ("noise_len", ctypes.c_uint32), ("noise_pos", ctypes.c_uint32), ("noise0_len", ctypes.c_uint32),
        *((name, ctypes.c_double) for name in (
            "theta_noise", "theta_dot_noise", "theta_offset", "theta_rad_per_count", "theta_dot_rad_s_per_count",
            "phi_rad_per_count")),
        *((name, ctypes.c_int32) for name in (
            "adc_min", "adc_max", "theta_offset_counts", "theta_wraps", "adc_bits", "bessel")),
        ("substep_hz", ctypes.c_double),
        ("plant_start_ns", ctypes.c_int64), ("substeps_done", ctypes.c_int64), ("pending", ctypes.c_int64),
        ("sessions_seen", ctypes.c_uint32), ("replacements", ctypes.c_uint32), ("reconfigured", ctypes.c_uint32),
        ("clock_ns", ctypes.c_uint64), ("period_ns", ctypes.c_uint32), ("output", ctypes.c_int32),
        ("theta_adc", ctypes.c_int32), ("theta_dot_adc", ctypes.c_int32), ("phi_count", ctypes.c_int32),
        ("out_len", ctypes.c_uint32), ("out_frames", ctypes.c_uint32),
        ("out_frame_len", ctypes.c_uint16 * OUT_FRAMES),
        ("out", ctypes.c_uint8 * OUT_BYTES),
    )


class LockstepServe(ctypes.Structure):
    """hil_mock/csrc/device.c ``hil_serve_t``: hil_lockstep's orders and what it did (see there)."""

    _fields_ = (
        ("fd", ctypes.c_int32), ("max_rounds", ctypes.c_uint32), ("interrupt", ctypes.c_int32),
        ("phase", ctypes.c_int32), ("event_substeps", ctypes.c_int64), ("timeout_ns", ctypes.c_int64),
        ("drained", ctypes.c_int32), ("realtime", ctypes.c_int32), ("error", ctypes.c_int32),
        ("status", ctypes.c_uint32), ("rounds", ctypes.c_uint32), ("timed_rounds", ctypes.c_uint32),
        ("reads", ctypes.c_uint32), ("writes", ctypes.c_uint32), ("selects", ctypes.c_uint32),
        ("written", ctypes.c_uint32),
        ("round_start_ns", ctypes.c_int64), ("round_clock_ns", ctypes.c_int64), ("until_ns", ctypes.c_int64),
        ("sum_work_s", ctypes.c_double), ("worst_work_s", ctypes.c_double),
    )


@functools.cache
def load_device_library() -> ctypes.CDLL:
    """hil_mock's device in C: the firmware core, its host HAL, plant.c and device.c, one library."""
    lib = ctypes.CDLL(str(host_library(
        sources=(*SOURCES, PLANT_SOURCE, DEVICE_SOURCE), headers=(*HEADERS, PLANT_HEADER), name="libhil_device",
        libs=("-lm",), include_dirs=(PLANT_SOURCE.parent,))))
    dev = ctypes.POINTER(HilDevice)
    u32 = ctypes.c_uint32
    for name, args in (("hil_rx", (dev, ctypes.c_char_p, ctypes.c_size_t)), ("hil_tick", (dev, ctypes.c_int)),
                       ("hil_advance", (dev,)), ("hil_skip", (dev, u32)), ("hil_poll", (dev,)),
                       ("hil_lockstep", (dev, ctypes.POINTER(LockstepServe)))):
        fn = getattr(lib, name)
        fn.argtypes = args
        fn.restype = u32
    for size, struct in ((lib.hil_device_size, HilDevice), (lib.hil_serve_size, LockstepServe)):
        size.restype = ctypes.c_size_t
        if size() != ctypes.sizeof(struct):
            raise RuntimeError(f"hil_mock/csrc/device.c and c_firmware.{struct.__name__} differ in size")
    _declare_core(lib)
    return lib


class ActuationTable:
    """(τ0, d, command) of each COMMAND count −32768…32767 at 3·(count + 32768), for device.c: the actuator's shaping
    (Actuator.torque_terms) of the command the count stands for, filled as the core first outputs each count (NaN
    until then) — the one definition of the shaping, looked up in C."""

    def __init__(self, actuator: Actuator, full_scale: float) -> None:
        self.actuator, self.full_scale = actuator, full_scale
        self.values = np.full(3 * 65536, np.nan)
        self.pointer = self.values.ctypes.data_as(_DP)

    def fill(self, counts: int) -> None:
        u = float(counts_to_actuator(counts, self.full_scale))
        i = 3 * (counts + 32768)
        self.values[i:i + 3] = (*self.actuator.torque_terms(u), u)


class _Held:
    """A Firmware attribute whose value lives in C (the core, device.c), read there on access. Firmware.__init__'s
    assignments, made before the C side exists, are what it reads meanwhile; later ones are refused."""

    __slots__ = ("key", "read")

    def __init__(self, read: Callable[[CFirmware], Any]) -> None:
        self.read = read
        self.key = ""

    def __set_name__(self, owner: type, name: str) -> None:
        self.key = "_before_c_" + name

    def __get__(self, fw: CFirmware | None, owner: type | None = None) -> Any:
        if fw is None:
            return self
        if "_d" not in fw.__dict__:
            return fw.__dict__.get(self.key, 0)
        return self.read(fw)

    def __set__(self, fw: CFirmware, value: object) -> None:
        if "_d" in fw.__dict__:
            raise AttributeError(f"{self.key[10:]} is the C firmware's: it changes through the protocol only")
        fw.__dict__[self.key] = value


def _core_field(field: str, kind: type = int) -> _Held:
    i = STATE_FIELDS.index(field)
    return _Held(lambda fw: kind(fw.core_state()[i]))


class _DecoderCounts:
    """The C stream decoder's counters, as hil_mock.device reads them from a StreamDecoder."""

    __slots__ = ("crc_errors", "errors", "frames_ok")

    def __init__(self, crc_errors: int = 0, errors: int = 0, frames_ok: int = 0) -> None:
        self.crc_errors, self.errors, self.frames_ok = crc_errors, errors, frames_ok


class CFirmware(Firmware):
    """hil_mock's device with the C firmware core making every protocol decision (see the module docstring)."""

    enabled = _core_field("enabled", bool)
    _any_applied = _core_field("any_applied", bool)
    output = _Held(lambda fw: counts_to_actuator(fw._d.output, fw.full_scale))
    streaming = _Held(lambda fw: bool(fw._bits & _STREAMING))
    clock_ns = _Held(lambda fw: fw._d.clock_ns)
    period_ns = _Held(lambda fw: fw._d.period_ns)
    plant_start_ns = _Held(lambda fw: None if fw._d.plant_start_ns < 0 else fw._d.plant_start_ns)
    substeps_done = _Held(lambda fw: fw._d.substeps_done)
    replacements = _Held(lambda fw: fw._d.replacements)
    decoder = _Held(lambda fw: _DecoderCounts(*(fw.core_state()[i] for i in (_CRC_ERRORS, _ERRORS, _FRAMES_OK))))

    def __init__(self, rig: RigConfig, model: RigModel, settings: DeviceSettings, rate_hz: int) -> None:
        super().__init__(rig, model, settings, rate_hz)  # the plant; its Python protocol state stays unused
        lib = self._lib = load_device_library()
        cal = self.model.calibration
        off = cal.theta_offset_counts
        self.board = Board(
            device_id=settings.device_id, default_rate_hz=rate_hz, max_rate_hz=int(min(MAX_RATE_HZ, self.substep_hz)),
            default_watchdog_ms=settings.watchdog_ms, theta_rad_per_count=cal.theta_rad_per_count,
            theta_offset_counts=off, theta_dot_rad_s_per_count=cal.theta_dot_rad_s_per_count,
            theta_dot_offset_counts=0, phi_counts_per_rev=cal.phi_counts_per_rev,
            actuator_full_scale=self.full_scale, actuator_kind=int(self.actuator_kind),
            # a full-turn θ sensor wraps instead of saturating: rails outside the i16 readings, never over-range
            theta_adc_min=-WRAPPING_RAIL if cal.theta_wraps else cal.adc_min + off,
            theta_adc_max=WRAPPING_RAIL if cal.theta_wraps else cal.adc_max + off,
            theta_dot_adc_min=cal.adc_min, theta_dot_adc_max=cal.adc_max,
        )
        self._core = ctypes.create_string_buffer(lib.host_device_size())
        self._state = (ctypes.c_uint64 * len(STATE_FIELDS))()
        lib.host_device_init(self._core, ctypes.byref(self.board))
        d = HilDevice(fw=ctypes.cast(self._core, ctypes.c_void_p), plant_start_ns=-1, substep_hz=self.substep_hz)
        self.fused = isinstance(self.sim, CompiledSimulator)
        if self.fused:
            self._attach_plant(d, cal)
        self._d = d
        self._dref = ctypes.byref(d)
        self._out = ctypes.addressof(d.out)
        self._bits = 0
        self._serve = LockstepServe()
        self._serve_ref = ctypes.byref(self._serve)
        self._after(lib.hil_poll(self._dref))

    def _attach_plant(self, d: HilDevice, cal: Calibration) -> None:
        """Point device.c at the compiled simulator's arrays, its initial state, the sensor path and the noise."""
        sim = self.sim
        assert isinstance(sim, CompiledSimulator)
        m = self.model
        d.params = ctypes.addressof(sim._params)
        d.state, d.ring = ctypes.cast(sim._state, _DP), ctypes.cast(sim._ring, _DP)
        d.head = ctypes.cast(ctypes.byref(sim._head), ctypes.POINTER(ctypes.c_int32))
        d.n_delay = sim._n_delay
        self._state0 = (ctypes.c_double * len(sim._state))(*sim._state)  # the rig at its initial state
        self._ring0 = (ctypes.c_double * len(sim._ring))(*sim._ring)
        d.state0, d.ring0 = ctypes.cast(self._state0, _DP), ctypes.cast(self._ring0, _DP)
        self._actuation = ActuationTable(m.actuator, self.full_scale)
        d.actuation = self._actuation.pointer
        d.theta_noise, d.theta_dot_noise, d.theta_offset = m.theta_noise, m.theta_dot_noise, m.theta_offset
        d.bessel = int(m.bessel is not None)
        d.theta_rad_per_count, d.theta_dot_rad_s_per_count = cal.theta_rad_per_count, cal.theta_dot_rad_s_per_count
        d.phi_rad_per_count, d.adc_bits = cal.phi_rad_per_count, cal.adc_bits
        d.adc_min, d.adc_max, d.theta_offset_counts = cal.adc_min, cal.adc_max, cal.theta_offset_counts
        d.theta_wraps = int(cal.theta_wraps)
        if m.theta_noise or m.theta_dot_noise:  # the simulator's generator, drawn in blocks in the reference's order
            self._noise0 = sim.rng.standard_normal(NOISE_BLOCK)
            self._noise = self._noise0
            d.noise = d.noise0 = self._noise0.ctypes.data_as(_DP)
            d.noise_len = d.noise0_len = NOISE_BLOCK

    # ------------------------------------------------------------ the C side
    def core_state(self) -> list[int]:
        """The core's state now, in the order of STATE_FIELDS."""
        self._lib.host_state(self._core, self._state)
        return self._state[:]

    def _after(self, bits: int) -> None:
        """After each call: frames out, a new session, the noise block, the Python plant's substeps."""
        self._bits = bits
        if bits & _SLOW:
            d = self._d
            if bits & _FRAMES:
                if d.out_frames == 1:  # the common tick: one SAMPLE
                    self.tx.append(ctypes.string_at(self._out, d.out_len))
                else:
                    raw = ctypes.string_at(self._out, d.out_len)
                    pos = 0
                    for length in d.out_frame_len[:d.out_frames]:
                        self.tx.append(raw[pos:pos + length])
                        pos += length
                d.out_len = d.out_frames = 0
            if bits & _NEW_SESSION:  # a HELLO to an idle device: as Firmware._on_hello
                if self.fused:  # device.c put the state back; the generator restarts from the seed
                    self.sim.rng = np.random.default_rng(self.settings.seed)
                    self.sim.rng.standard_normal(NOISE_BLOCK if self.model.theta_noise or self.model.theta_dot_noise
                                                 else 0)
                    self._noise = self._noise0 if hasattr(self, "_noise0") else None
                    self.sim.t = 0.0
                else:
                    self.sim = self._new_plant()
            if bits & _NOISE_LOW:
                left = self._noise[d.noise_pos:d.noise_len]
                self._noise = np.concatenate((left, self.sim.rng.standard_normal(NOISE_BLOCK)))
                d.noise = self._noise.ctypes.data_as(_DP)
                d.noise_len, d.noise_pos = len(self._noise), 0
            if bits & _NO_NOISE:
                raise RuntimeError("hil_mock/csrc/device.c ran out of noise draws")
            if bits & _SHAPE:  # counts the actuator had not output before: shape them, then the plant moves on
                self._actuation.fill(d.output)
                self._after(self._lib.hil_advance(self._dref))
                return
        if not self.fused and self._d.pending:
            self.sim.set_command(self.output)
            self.sim.advance(self._d.pending)
            self._d.pending = 0

    @property
    def answered(self) -> bool:
        return bool(self._bits & _ANSWERED)

    @property
    def reconfigured(self) -> bool:
        return bool(self._bits & _RECONFIGURED)

    @property
    def status_flags(self) -> int:
        return self.core_state()[_STATUS_FLAGS]

    @property
    def armed(self) -> bool:
        return self.streaming and self._any_applied

    def status(self) -> Status:
        raise NotImplementedError("the C core builds its own STATUS frames: decode them from tx")

    def hello_ack(self, nonce: int) -> HelloAck:
        raise NotImplementedError("the C core builds its own HELLO_ACK: decode it from tx")

    # ------------------------------------------------------------ lockstep rounds in C
    def serve_lockstep(self, fd: int, max_rounds: int, event_substeps: int, timeout_s: float
                       ) -> tuple[LockstepServe, bytes]:
        """Lockstep rounds on ``fd`` (device.c hil_lockstep) until the loop must act, ``max_rounds`` of them, or the
        plant reaching ``event_substeps``; the compiled plant only. Returns what the rounds did and, when the pty
        took only part of a tick's frames, the bytes it left (the caller's backlog)."""
        s = self._serve
        s.fd, s.max_rounds, s.event_substeps, s.timeout_ns = fd, max_rounds, event_substeps, round(timeout_s * 1e9)
        self._lib.hil_lockstep(self._dref, self._serve_ref)
        rest = b""
        if s.phase == AFTER_WRITE and s.written < self._d.out_len:
            d = self._d
            rest = ctypes.string_at(self._out + s.written, d.out_len - s.written)
            d.out_len = d.out_frames = 0
            s.status &= ~_FRAMES
        self._after(s.status)
        return s, rest

    def interrupt_lockstep(self, on: bool = True) -> None:
        """Ask running lockstep rounds to return at their next check (any thread); ``on=False`` clears it."""
        self._serve.interrupt = int(on)

    # ------------------------------------------------------------ Firmware's interface
    def receive(self, data: bytes) -> None:
        self._after(self._lib.hil_rx(self._dref, bytes(data), len(data)))

    def tick(self, advance: bool = True) -> None:
        if not self.fused and self._bits & _STREAMING:  # the Python plant's readings for the HAL
            raw = self.sim.sample()
            d = self._d
            d.theta_adc, d.theta_dot_adc, d.phi_count = raw.theta_adc, raw.theta_dot_adc, raw.phi_count
        self._after(self._lib.hil_tick(self._dref, advance))

    def advance_plant(self) -> None:
        self._after(self._lib.hil_advance(self._dref))

    def skip(self, periods: int) -> None:
        if periods > 0:
            self._after(self._lib.hil_skip(self._dref, periods))

    def reboot(self, cause: ResetCause = ResetCause.PIN) -> None:
        self.tx.clear()
        self._d.out_len = self._d.out_frames = 0
        self.reset_cause = cause
        self._lib.host_reboot(self._core, int(cause))
        self._after(self._lib.hil_poll(self._dref))

    def set_uart_errors(self, overruns: int, line_errors: int) -> None:
        self.uart_overruns, self.uart_line_errors = overruns, line_errors
        self._lib.host_uart_errors(self._core, overruns & 0xFFFFFFFF, line_errors & 0xFFFFFFFF)

    def hangup(self) -> None:
        self._lib.host_hangup(self._core)
        self._after(self._lib.hil_poll(self._dref))

    def note_tx_overflow(self) -> None:
        self._lib.host_note_tx_overflow(self._core)
        self._after(self._lib.hil_poll(self._dref))


for _name in _COUNTERS:  # the core's counters and configuration, read where they live
    _field = _core_field(_name)
    _field.__set_name__(CFirmware, _name)
    setattr(CFirmware, _name, _field)


def make_firmware(kind: str, rig: RigConfig, model: RigModel, settings: DeviceSettings, rate_hz: int) -> Firmware:
    """The device logic hil_mock runs: ``python`` (hil_mock.firmware), ``c`` (the microcontroller's C core) or
    ``board`` (the flashed image on the board model)."""
    if kind == "board":
        from hil_mock.board_model.device import BoardFirmware  # unicorn only when asked for

        return BoardFirmware(rig, model, settings, rate_hz)
    if kind == "c":
        return CFirmware(rig, model, settings, rate_hz)
    if kind == "python":
        return Firmware(rig, model, settings, rate_hz)
    raise ValueError(f"firmware {kind!r}: choose python, c or board")
