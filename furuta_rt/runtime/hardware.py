"""The hardware interface of the loop (ros2_control style: read → update → write) and its serial DAQ
implementation over firmware_protocol.

``SerialHardware`` opens the port, performs the handshake (HELLO → HELLO_ACK with protocol version,
schema hash and nonce checked; CONFIG → STATUS with the loop rate and watchdog), then ``read`` blocks
on the device's SAMPLE stream (the device is the clock) and ``write`` sends one COMMAND per tick.
Reads are non-blocking ``os.read`` calls after ``poll``, fed to a StreamDecoder; everything the
device sends in one burst is buffered, and ``pending`` tells the loop that a newer SAMPLE is already
waiting (the current one is stale: its period was missed).
"""

from __future__ import annotations

import contextlib
import errno
import math
import os
import select
import time
from abc import ABC, abstractmethod
from collections import deque
from dataclasses import dataclass
from pathlib import Path

from firmware_protocol import (
    ActuatorKind,
    Config,
    HandshakeError,
    HelloAck,
    ResetCause,
    Sample,
    Status,
    StatusFlags,
    Stop,
    StreamDecoder,
    encode,
    encode_command,
    make_hello,
    verify_hello_ack,
    zero_answer,
)
from furuta_rt.errors import UserError
from furuta_rt.model.sensors import Calibration

USB_SERIAL_SYSFS = "/sys/bus/usb-serial/devices"


class LinkLost(Exception):
    """The device vanished (EOF, EIO: ``gone``) or stopped answering or reading."""

    def __init__(self, message: str, gone: bool = True) -> None:
        super().__init__(message)
        self.gone = gone


@dataclass(frozen=True, slots=True)
class DeviceInfo:
    """What the handshake established: identity, calibration, actuator scaling, applied rate."""

    ack: HelloAck
    rate_hz: int
    watchdog_ms: int

    @property
    def calibration(self) -> Calibration:
        a = self.ack
        return Calibration(
            theta_rad_per_count=a.theta_rad_per_count,
            theta_offset_counts=a.theta_offset_counts,
            theta_dot_rad_s_per_count=a.theta_dot_rad_s_per_count,
            phi_counts_per_rev=a.phi_counts_per_rev,
        )

    @property
    def theta_dot_offset_counts(self) -> int:
        return self.ack.theta_dot_offset_counts

    @property
    def full_scale(self) -> float:
        return self.ack.actuator_full_scale

    @property
    def actuator_kind(self) -> str:
        kind = self.ack.actuator_kind
        if kind == ActuatorKind.TORQUE_NM:
            return "torque"
        return "dc_motor" if kind == ActuatorKind.VOLTAGE_V else f"unknown kind {kind}"

    def implausible(self) -> str | None:
        """What in the HELLO_ACK no rig can use (PROTOCOL.md's field ranges), or None."""
        a = self.ack
        if a.actuator_kind not in tuple(ActuatorKind):
            return f"actuator_kind = {a.actuator_kind} is none of {', '.join(f'{k.value} ({k.name})' for k in ActuatorKind)}"
        if a.phi_counts_per_rev <= 0:
            return f"phi_counts_per_rev = {a.phi_counts_per_rev} (the arm encoder needs > 0 counts per revolution)"
        for name in ("theta_rad_per_count", "theta_dot_rad_s_per_count", "actuator_full_scale"):
            v = getattr(a, name)
            if not (math.isfinite(v) and v > 0):
                return f"{name} = {v:g} (must be a finite scale > 0)"
        return None

    @property
    def reset_cause(self) -> str:
        """Why the device last started, in words (HELLO_ACK.reset_cause)."""
        try:
            cause = ResetCause(self.ack.reset_cause)
        except ValueError:
            return f"unknown reset cause {self.ack.reset_cause}"
        return RESET_WORDS[cause]

    def reset_warning(self) -> str | None:
        """What a user must hear on connect: the device's last start was its watchdog's or its fault handler's."""
        if self.ack.reset_cause == ResetCause.WATCHDOG:
            return ("the device was last reset by its watchdog (the firmware hung, or its tick stalled); "
                    "if that was not a power-up or the reset button, check the firmware and its wiring")
        if self.ack.reset_cause == ResetCause.FAULT:
            return ("the device was last reset after a fault in its firmware (its fault handler took the drive off); "
                    "attach a debugger or reflash before trusting it")
        return None

    @property
    def firmware(self) -> str:
        a = self.ack
        return f"{a.fw_major}.{a.fw_minor}.{a.fw_patch}"

    def metadata(self) -> dict[str, str]:
        """The HELLO_ACK fields and the applied CONFIG, as MCAP metadata strings."""
        out = {name: str(getattr(self.ack, name)) for name in self.ack.__dataclass_fields__}
        out["device_id"] = f"{self.ack.device_id:#010x}"
        out["schema_hash"] = f"{self.ack.schema_hash:#010x}"
        out["applied_rate_hz"] = str(self.rate_hz)
        out["applied_watchdog_ms"] = str(self.watchdog_ms)
        out["reset_cause"] = self.reset_cause
        return out


RESET_WORDS = {
    ResetCause.UNKNOWN: "reset cause unknown",
    ResetCause.POWER_ON: "power-on",
    ResetCause.PIN: "reset pin",
    ResetCause.WATCHDOG: "watchdog reset",
    ResetCause.SOFTWARE: "software reset",
    ResetCause.FAULT: "fault reset",
}


class HardwareInterface(ABC):
    """What the loop needs from a device. ``read`` → update → ``write``, once per device tick."""

    arrival_ns: int = 0
    """perf_counter_ns when the bytes of the sample last returned by ``read`` were received."""

    @abstractmethod
    def handshake(self, rate_hz: int, watchdog_ms: int) -> DeviceInfo: ...

    @abstractmethod
    def read(self, timeout: float) -> Sample | None:
        """The next SAMPLE in stream order, or None if none arrived within ``timeout`` s."""

    @property
    @abstractmethod
    def pending(self) -> int:
        """Samples already received behind the one last returned (> 0: that one is stale)."""

    @abstractmethod
    def write(self, seq: int, counts: int, flags: int) -> None:
        """Send the COMMAND answering SAMPLE ``seq`` (the whole frame, or raise LinkLost)."""

    @abstractmethod
    def stop(self) -> str | None:
        """Zero the actuator now: u = 0 with ENABLE clear answering the newest SAMPLE received, when a
        device following PROTOCOL.md §6 accepts it (``zero_answer``), then STOP (§4: zero at once,
        whatever seq the device last accepted). Never raises: None once both went out, else why not
        (a later call tries again)."""

    @abstractmethod
    def close(self) -> None: ...

    @property
    def crc_errors(self) -> int:
        return 0

    def counters(self) -> dict[str, int]:
        return {}


def _user_error_for_open(port: str, err: Exception) -> UserError:
    code = getattr(err, "errno", None)
    if code is None and err.args and isinstance(err.args[0], int):
        code = err.args[0]
    if code == errno.EISDIR or os.path.isdir(port):
        return UserError(f"--port {port} is a directory; give the DAQ's device, e.g. /dev/ttyACM0 (list devices: "
                         "python -m serial.tools.list_ports), or use --mock")
    if code == errno.ENOENT:
        return UserError(f"serial device {port} does not exist; check --port (list devices: python -m serial.tools.list_ports), "
                         "or use --mock to run against the simulated pendulum")
    if code in (errno.EACCES, errno.EPERM):
        return UserError(f"permission denied opening {port}; add yourself to the serial group "
                         "(sudo usermod -aG dialout $USER, then log in again)")
    if code == errno.EBUSY or "lock" in str(err).lower():
        return UserError(f"serial device {port} is busy (another program has it open); close it and retry")
    if code == errno.ENOTTY or os.strerror(errno.ENOTTY).lower() in str(err).lower():
        return UserError(f"{port} is not a serial port (it takes no serial settings); give the DAQ's device, e.g. "
                         "/dev/ttyACM0 (list devices: python -m serial.tools.list_ports), or use --mock")
    return UserError(f"cannot open serial device {port}: {err}")


class SerialHardware(HardwareInterface):
    """The DAQ over a serial port (USB CDC, FTDI, or hil_mock's pseudo-terminal)."""

    HANDSHAKE_RETRY_S = 0.1
    HANDSHAKE_TRIES = 20
    CONFIG_TIMEOUT_S = 2.0
    WRITE_TIMEOUT_S = 0.05
    """A frame the port does not take whole within this long: the device is not reading (LinkLost)."""
    STOP_TIMEOUT_S = 0.5

    def __init__(self, port: str, baudrate: int = 1_000_000) -> None:
        self.port = port
        self.baudrate = baudrate
        self.decoder = StreamDecoder()
        self._ser = None
        self._fd = -1
        self._poll = select.poll()
        self._wpoll = select.poll()
        self._queue: deque[Sample] = deque()
        self._last_seq: int | None = None  # newest SAMPLE returned by read() in this session
        self._written: int | None = None  # seq of the last COMMAND written whole in this session
        self._torn = False  # a frame went out in part: the device's decoder needs a delimiter first
        self._session = 0  # the nonce of the HELLO the device streams for: every COMMAND carries it (PROTOCOL.md §6)
        self.arrival_ns = 0
        self.status: Status | None = None
        self.write_errors = 0
        self.samples = 0
        self.info: DeviceInfo | None = None
        self.warnings: list[str] = []
        self._stopped = False

    # ---------------------------------------------------------------- setup
    def open(self) -> None:
        """Open and lock the port (no traffic yet). Raises UserError naming the fix."""
        import serial  # pyserial; imported here so the module is importable without it

        try:
            self._ser = serial.Serial(self.port, self.baudrate, timeout=0, exclusive=True)
        except (serial.SerialException, OSError, ValueError) as err:
            raise _user_error_for_open(self.port, err) from None
        self._fd = self._ser.fileno()
        self._poll.register(self._fd, select.POLLIN)
        self._wpoll.register(self._fd, select.POLLOUT)
        warning = check_usb_latency(self.port, self._ser)
        if warning:
            self.warnings.append(warning)

    def _send(self, frame: bytes, timeout: float | None = None) -> None:
        """Write the whole frame, waiting up to ``timeout`` s (default WRITE_TIMEOUT_S) for the port to
        take the rest; LinkLost if it does not, or if the port fails. A frame cut short would corrupt
        the next one too (PROTOCOL.md §2.1), so the next frame starts with a delimiter."""
        if not self._torn:  # the common case: the port takes the whole frame in one write
            try:
                n = os.write(self._fd, frame)
            except BlockingIOError:
                n = 0
            except OSError as err:
                raise LinkLost(f"write to {self.port} failed: {err}") from None
            if n == len(frame):
                return
            view = memoryview(frame)[n:]
        else:
            frame = b"\x00" + frame
            view = memoryview(frame)
        self._send_rest(frame, view, self.WRITE_TIMEOUT_S if timeout is None else timeout)

    def _send_rest(self, frame: bytes, view: memoryview, limit: float) -> None:
        """Write ``view`` (the part of ``frame`` not yet taken) as the port takes it: write, then wait for room."""
        start = None
        while True:
            try:
                n = os.write(self._fd, view)
            except BlockingIOError:
                n = 0
            except OSError as err:
                self._torn = self._torn or len(view) < len(frame)
                raise LinkLost(f"write to {self.port} failed: {err}") from None
            view = view[n:]
            if not view:
                self._torn = False
                return
            now = time.perf_counter()
            if start is None:
                start = now
            elif now - start >= limit:
                self.write_errors += 1
                self._torn = self._torn or len(view) < len(frame)
                raise LinkLost(f"write to {self.port} stalled: the port took {len(frame) - len(view)} of {len(frame)} "
                               f"bytes of a frame in {(now - start) * 1e3:.0f} ms (the device is not reading)", gone=False)
            self._wpoll.poll(max(1, math.ceil((limit - (now - start)) * 1000.0)))

    def _receive(self, timeout: float) -> list:
        """Messages received within ``timeout`` s (at least one poll)."""
        if self._poll.poll(max(0, math.ceil(timeout * 1000.0))):
            self.arrival_ns = time.perf_counter_ns()
            try:
                data = os.read(self._fd, 4096)
            except BlockingIOError:
                return []
            except OSError as err:
                raise LinkLost(f"read from {self.port} failed: {err}") from None
            if not data:
                raise LinkLost(f"{self.port} closed (end of file)")
            return self.decoder.feed(data)
        return []

    def _await(self, kind: type, timeout: float) -> object | None:
        """The first message of ``kind`` within ``timeout`` s; SAMPLEs before it are queued for ``read``. (Those that
        share its read are dropped: queuing them answers a lockstep mock's first SAMPLE 1 s sooner but shifts the
        run by a tick, which moved test_compensation_hil's adaptive-vs-matched std φ from 1.02x to 1.42x.)"""
        end = time.monotonic() + timeout
        while (left := end - time.monotonic()) > 0:
            for msg in self._receive(left):
                if isinstance(msg, kind):
                    return msg
                if isinstance(msg, Sample):
                    self._queue.append(msg)
                elif isinstance(msg, Status):
                    self.status = msg
        return None

    def _last_session(self, ack: HelloAck, latest: int) -> HelloAck:
        """The HELLO_ACK of the session the device ends up streaming. An ACK that answers an earlier HELLO (a device
        slow to answer the first) may be followed by the answer to a later one, and every HELLO restarts the session
        at seq 0 (PROTOCOL.md §5): wait one retry period for it, and drop the SAMPLEs of the session it replaced."""
        while ack.nonce != latest:
            later = self._await(HelloAck, self.HANDSHAKE_RETRY_S)
            if later is None:  # the later HELLO never reached the device
                break
            self._queue.clear()
            ack = later  # type: ignore[assignment]
        return ack

    def handshake(self, rate_hz: int, watchdog_ms: int) -> DeviceInfo:
        """HELLO/HELLO_ACK (version, schema hash, nonce) then CONFIG/STATUS. Raises UserError."""
        if self._ser is None:
            self.open()
        try:
            return self._handshake(rate_hz, watchdog_ms)
        except LinkLost as err:
            raise UserError(f"the device on {self.port} went away during the handshake ({err}); "
                            "check its cable and power, then retry") from None

    def _handshake(self, rate_hz: int, watchdog_ms: int) -> DeviceInfo:
        self._ser.reset_input_buffer()  # type: ignore[attr-defined]
        self.decoder.reset()
        self._stopped = False
        self._last_seq = self._written = None
        ack = None
        hellos: dict[int, object] = {}
        self._send(b"\x00")  # PROTOCOL.md §2.1: flush any partial frame at the device
        for _ in range(self.HANDSHAKE_TRIES):  # §5: retry every 100 ms (first bytes after open can be lost)
            hello = make_hello()
            hellos[hello.nonce] = hello
            self._send(encode(hello))
            ack = self._await(HelloAck, self.HANDSHAKE_RETRY_S)
            if ack is not None:
                ack = self._last_session(ack, hello.nonce)
                hello = hellos.get(ack.nonce, hello)  # type: ignore[attr-defined]  # answers an earlier HELLO
                break
        if ack is None:
            waited = self.HANDSHAKE_TRIES * self.HANDSHAKE_RETRY_S
            raise UserError(f"no HELLO_ACK from {self.port} within {waited:g} s: is it a furuta DAQ, powered, "
                            f"at --baud {self.baudrate}?")
        try:
            verify_hello_ack(ack, hello)  # type: ignore[arg-type]
        except HandshakeError as err:
            raise UserError(f"handshake with {self.port} failed: {err}; flash firmware built from this "
                            "firmware_protocol version") from None
        self._session = ack.nonce  # type: ignore[attr-defined]
        if ack.sample_rate_hz == rate_hz and ack.watchdog_ms == watchdog_ms:  # type: ignore[attr-defined]
            self.info = DeviceInfo(ack=ack, rate_hz=rate_hz, watchdog_ms=watchdog_ms)  # type: ignore[arg-type]
        else:  # PROTOCOL.md §5: CONFIG is needed only to change what the HELLO_ACK reports
            self._queue.clear()
            self._send(encode(Config(rate_hz=rate_hz, watchdog_ms=watchdog_ms)))
            status = self._await(Status, self.CONFIG_TIMEOUT_S)
            if status is None:
                raise UserError(f"{self.port} did not answer CONFIG with a STATUS; check the firmware")
            self.status = status  # type: ignore[assignment]
            if status.flags & StatusFlags.CONFIG_REJECTED or status.rate_hz != rate_hz:  # type: ignore[attr-defined]
                in_force = f"{status.rate_hz} Hz / {status.watchdog_ms} ms"  # type: ignore[attr-defined]
                raise UserError(f"the device rejected rate {rate_hz} Hz / watchdog {watchdog_ms} ms (it runs at "
                                f"{in_force}); choose values the firmware supports with --rate and --watchdog-ms")
            self.info = DeviceInfo(ack=ack, rate_hz=status.rate_hz, watchdog_ms=status.watchdog_ms)  # type: ignore[arg-type, attr-defined]
        while len(self._queue) > 1:  # older samples are not ticks of this run; the newest is answered first
            self._queue.popleft()
        return self.info

    # ---------------------------------------------------------------- per tick
    def read(self, timeout: float) -> Sample | None:
        q = self._queue
        if not q:
            end = time.perf_counter() + timeout
            while True:
                for msg in self._receive(timeout):
                    if type(msg) is Sample:
                        q.append(msg)
                    elif type(msg) is Status:
                        self.status = msg
                if q:
                    break
                timeout = end - time.perf_counter()
                if timeout <= 0:
                    return None
        self.samples += 1
        s = q.popleft()
        self._last_seq = s.seq
        return s

    @property
    def pending(self) -> int:
        return len(self._queue)

    def write(self, seq: int, counts: int, flags: int) -> None:
        self._send(encode_command(self._session, seq, counts, flags))
        self._written = seq

    def _drain(self) -> None:
        """Take in what the device already sent, without waiting (a newer SAMPLE can then get the zero)."""
        for _ in range(64):
            if not self._poll.poll(0):
                return
            try:
                data = os.read(self._fd, 4096)
            except OSError:
                return
            if not data:
                return
            for msg in self.decoder.feed(data):
                if type(msg) is Sample:
                    self._queue.append(msg)

    def stop(self) -> str | None:
        if self._fd < 0:
            return "the port is closed"
        if self._stopped:
            return None
        self._drain()
        newest = self._queue[-1].seq if self._queue else self._last_seq
        seq = zero_answer(newest, self._written)
        # STOP twice: on a noisy link one corrupted frame must not leave the actuator enabled (the device
        # drops a bad frame silently; a second STOP is harmless). A second zero COMMAND would be discarded.
        frames = ([] if seq is None else [encode_command(self._session, seq, 0, 0)]) + [encode(Stop(reason=0))] * 2
        try:
            for frame in frames:
                self._send(frame, self.STOP_TIMEOUT_S)
        except LinkLost as err:
            return str(err)
        if seq is not None:
            self._written = seq
        self._stopped = True
        with contextlib.suppress(Exception):  # best effort on a dying link
            self._ser.flush()  # type: ignore[attr-defined]  # tcdrain: the frames are on the wire
        return None

    def close(self) -> None:
        if self._ser is not None:
            try:
                self._poll.unregister(self._fd)
                self._ser.close()
            except Exception:
                pass
            self._ser = None
            self._fd = -1

    @property
    def crc_errors(self) -> int:
        return self.decoder.crc_errors

    def counters(self) -> dict[str, int]:
        out = {f"rx_{k}": v for k, v in self.decoder.counters().items()}
        out["tx_write_errors"] = self.write_errors
        if self.status is not None:
            out["device_crc_errors"] = self.status.crc_errors
            out["device_frame_errors"] = self.status.frame_errors
            out["device_uart_overruns"] = self.status.uart_overruns
            out["device_uart_line_errors"] = self.status.uart_line_errors
        return out


# ------------------------------------------------------------------ USB latency timer
def usb_serial_name(port: str) -> str | None:
    """'ttyUSB0' for /dev/ttyUSB0 or a /dev/serial/by-id link to it; None if not a usb-serial tty."""
    name = Path(os.path.realpath(port)).name
    return name if name.startswith("ttyUSB") else None


def read_latency_timer(name: str, sysfs: str = USB_SERIAL_SYSFS) -> int | None:
    try:
        return int((Path(sysfs) / name / "latency_timer").read_text().strip())
    except (OSError, ValueError):
        return None


def check_usb_latency(port: str, ser: object | None = None, sysfs: str = USB_SERIAL_SYSFS) -> str | None:
    """A warning if ``port`` is a USB-serial adapter whose latency timer is above 1 ms, else None.

    FTDI-style adapters hold received bytes up to ``latency_timer`` ms (default 16) before sending a
    USB packet: a SAMPLE would reach the host up to 16 ms late. pyserial's set_low_latency_mode asks
    the driver for 1 ms; if that does not take, the message says how to set it.
    """
    name = usb_serial_name(port)
    if name is None:
        return None
    value = read_latency_timer(name, sysfs)
    if value is None or value <= 1:
        return None
    if ser is not None and hasattr(ser, "set_low_latency_mode"):
        with contextlib.suppress(ValueError, OSError):
            ser.set_low_latency_mode(True)
        after = read_latency_timer(name, sysfs)
        if after is not None and after <= 1:
            return None
        value = after if after is not None else value
    return (f"{port} ({name}) has a USB latency timer of {value} ms: samples arrive up to {value} ms late. "
            f"Fix: echo 1 | sudo tee {sysfs}/{name}/latency_timer  (permanent: a udev rule "
            f'ACTION=="add", SUBSYSTEM=="usb-serial", DRIVER=="ftdi_sio", ATTR{{latency_timer}}="1")')
