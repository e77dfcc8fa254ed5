"""The C firmware core (firmware_protocol/firmware) as hil_mock's device logic: ``hil-mock --firmware c``.

``CFirmware`` is a drop-in for hil_mock.firmware.Firmware: the same plant, sensor and actuator models (inherited:
the simulator, its initial state, the rig put back at a new session, the plant advanced in device time), with the
protocol decisions — handshake, CONFIG, command acceptance, watchdog, faults, every byte sent — made by the C
code that runs on the microcontroller, built for the host (firmware_protocol.hostbuild) and called through
ctypes. The host HAL (firmware/host/host_hal.c) is fed the plant's ADC and encoder readings before each tick, and
its actuator counts drive the plant after it: the C never calls back into Python.
"""

from __future__ import annotations

import ctypes
import functools

from firmware_protocol import HelloAck, ResetCause, Status, counts_to_actuator
from firmware_protocol.hostbuild import host_library
from furuta_rt.config import RigConfig
from furuta_rt.model.rig import RigModel
from hil_mock.config import MAX_RATE_HZ, DeviceSettings
from hil_mock.firmware import Firmware

WRAPPING_RAIL = 1 << 20  # beyond every int16 reading
TX_BYTES = 2048  # host_hal.c HOST_TX_BYTES
TX_FRAMES = 64  # host_hal.c HOST_TX_FRAMES
STATE_FIELDS = (
    "clock_ns", "period_ns", "rate_hz", "watchdog_ms", "streaming", "enabled", "answered", "any_applied",
    "output_counts", "faults", "status_flags", "new_sessions", "tx_frames", "commands_rx", "commands_applied",
    "commands_discarded", "watchdog_trips", "handshakes", "handshakes_refused", "samples_sent", "status_sent",
    "hangups", "reboots", "frames_ok", "crc_errors", "errors", "seq", "last_cmd_seq", "commands_other_session",
)  # host_hal.c host_state()
_COUNTERS = ("commands_rx", "commands_applied", "commands_discarded", "watchdog_trips", "handshakes",
             "handshakes_refused", "samples_sent", "status_sent", "hangups", "reboots", "rate_hz", "watchdog_ms",
             "period_ns", "clock_ns", "faults", "seq", "last_cmd_seq", "commands_other_session")
_COUNTER_INDEX = tuple((name, STATE_FIELDS.index(name)) for name in _COUNTERS)
(_TX_FRAMES, _STREAMING, _ENABLED, _ANSWERED, _ANY_APPLIED, _STATUS_FLAGS, _CRC_ERRORS, _ERRORS, _FRAMES_OK,
 _NEW_SESSIONS, _OUTPUT_COUNTS) = (STATE_FIELDS.index(name) for name in (
    "tx_frames", "streaming", "enabled", "answered", "any_applied", "status_flags", "crc_errors", "errors",
    "frames_ok", "new_sessions", "output_counts"))


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
    lib = ctypes.CDLL(str(host_library()))
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


class _DecoderCounts:
    """The C stream decoder's counters, as hil_mock.device reads them from a StreamDecoder."""

    __slots__ = ("crc_errors", "errors", "frames_ok")

    def __init__(self) -> None:
        self.crc_errors = self.errors = self.frames_ok = 0


class CFirmware(Firmware):
    """hil_mock's device with the C firmware core making every protocol decision (see the module docstring)."""

    def __init__(self, rig: RigConfig, model: RigModel, settings: DeviceSettings, rate_hz: int) -> None:
        super().__init__(rig, model, settings, rate_hz)  # the plant; its Python protocol state stays unused
        lib = self._lib = load_library()
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
        self._dev = ctypes.create_string_buffer(lib.host_device_size())
        self._state = (ctypes.c_uint64 * len(STATE_FIELDS))()
        self._tx_buf = ctypes.create_string_buffer(TX_BYTES)
        self._tx_len = (ctypes.c_uint16 * TX_FRAMES)()
        self._sessions_seen = 0
        self._counts = -1  # the output counts last applied (none yet)
        self.decoder = _DecoderCounts()  # type: ignore[assignment]
        lib.host_device_init(self._dev, ctypes.byref(self.board))
        self._sync()

    # ------------------------------------------------------------ the C side
    def _sync(self) -> None:
        """Read the C state after a call: frames out, counters, the actuator, a new session."""
        lib = self._lib
        lib.host_state(self._dev, self._state)
        s = self._state[:]
        if s[_TX_FRAMES]:
            n = lib.host_take_tx(self._dev, self._tx_buf, self._tx_len)
            raw, pos = self._tx_buf.raw, 0
            for length in self._tx_len[:n]:
                self.tx.append(raw[pos:pos + length])
                pos += length
        d = self.__dict__
        for name, i in _COUNTER_INDEX:
            d[name] = s[i]
        self.streaming = bool(s[_STREAMING])
        self.enabled = bool(s[_ENABLED])
        self._answered = bool(s[_ANSWERED])
        self._any_applied = bool(s[_ANY_APPLIED])
        self._flags = s[_STATUS_FLAGS]
        dec = self.decoder
        dec.crc_errors, dec.errors, dec.frames_ok = s[_CRC_ERRORS], s[_ERRORS], s[_FRAMES_OK]
        if s[_NEW_SESSIONS] != self._sessions_seen:  # a HELLO to an idle device: as Firmware._on_hello
            self._sessions_seen = s[_NEW_SESSIONS]
            if self.plant_start_ns is None:
                self.plant_start_ns = self.clock_ns
            else:
                self.sim = self._new_plant()
                self.replacements += 1
                self._counts = -1  # the new plant gets the output below
                self.output = 0.0
        counts = s[_OUTPUT_COUNTS]
        if counts != self._counts:  # the actuator's value only changes with the counts
            self._counts = counts
            self._set_output(counts_to_actuator(counts - 0x10000 if counts >= 0x8000 else counts, self.full_scale))

    @property
    def status_flags(self) -> int:
        return self._flags

    @property
    def armed(self) -> bool:
        return self.streaming and self._any_applied

    def status(self) -> Status:
        raise NotImplementedError("the C core builds its own STATUS frames: decode them from tx")

    def hello_ack(self, nonce: int) -> HelloAck:
        raise NotImplementedError("the C core builds its own HELLO_ACK: decode it from tx")

    # ------------------------------------------------------------ Firmware's interface
    def receive(self, data: bytes) -> None:
        self._lib.host_rx(self._dev, bytes(data), len(data))
        self._sync()

    def tick(self, advance: bool = True) -> None:
        if self.streaming:  # the HAL's readings: the ADCs and encoder of the plant now
            raw = self.sim.sample()
            self._lib.host_tick(self._dev, raw.theta_adc, raw.theta_dot_adc, raw.phi_count, 0)
        else:
            self._lib.host_tick(self._dev, 0, 0, 0, 0)
        self._sync()
        if advance:
            self.advance_plant()

    def skip(self, periods: int) -> None:
        if periods > 0:
            self._lib.host_skip(self._dev, periods)
            self._sync()
            self.advance_plant()

    def reboot(self, cause: ResetCause = ResetCause.PIN) -> None:
        self.tx.clear()
        self.reset_cause = cause
        self._lib.host_reboot(self._dev, int(cause))
        self._sync()

    def set_uart_errors(self, overruns: int, line_errors: int) -> None:
        self.uart_overruns, self.uart_line_errors = overruns, line_errors
        self._lib.host_uart_errors(self._dev, overruns & 0xFFFFFFFF, line_errors & 0xFFFFFFFF)

    def hangup(self) -> None:
        self._lib.host_hangup(self._dev)
        self._sync()

    def note_tx_overflow(self) -> None:
        self._lib.host_note_tx_overflow(self._dev)
        self._sync()


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
