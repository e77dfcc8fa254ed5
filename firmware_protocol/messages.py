"""Message definitions of the serial DAQ protocol: ids, fields, wire formats, flags.

Every message is a frozen slotted dataclass with a fixed-size little-endian body. The
``FORMAT`` class attribute lists one :mod:`struct` code per field, in field order; the
schema hash (:data:`SCHEMA_HASH`) is computed from these definitions, so changing a
field, its type, a message id or a flag bit changes the hash and the handshake fails.
"""

from __future__ import annotations

import hashlib
import math
import struct
from collections.abc import Callable
from dataclasses import dataclass, fields
from enum import IntEnum, IntFlag
from operator import attrgetter
from typing import Any, ClassVar

PROTOCOL_VERSION = 2
"""Bumped on any incompatible change of framing or semantics."""

COMMAND_FULL_SCALE = 32767
"""COMMAND.command counts that correspond to the actuator full scale (HelloAck.actuator_full_scale)."""

DEFAULT_WATCHDOG_MS = 20


class MsgType(IntEnum):
    """Message type id, the first byte of every frame. Bit 7 set: device → host."""

    HELLO = 0x01
    CONFIG = 0x02
    COMMAND = 0x03
    STOP = 0x04
    HELLO_ACK = 0x81
    SAMPLE = 0x82
    STATUS = 0x83


class StatusFlags(IntFlag):
    """Device status bits, shared by SAMPLE.status and STATUS.flags (u16)."""

    WATCHDOG_TRIPPED = 1 << 0  # latched fault: no valid COMMAND within watchdog_ms
    ADC_OVERRANGE = 1 << 1  # latched fault: theta or theta_dot ADC at a rail
    ENCODER_ERROR = 1 << 2  # latched fault: encoder signal error (illegal transition, ...)
    CRC_ERROR = 1 << 3  # device rejected >= 1 incoming frame since the previous SAMPLE
    ENABLED = 1 << 4  # actuator output is live (ENABLE set and no latched fault)
    COMMAND_LATE = 1 << 5  # no COMMAND answering the previous SAMPLE arrived before this tick
    TICK_OVERRUN = 1 << 6  # the device missed a tick deadline
    CONFIG_REJECTED = 1 << 7  # the last CONFIG was out of range and not applied
    TX_OVERFLOW = 1 << 8  # the device dropped outgoing frames (host not reading)


FAULT_MASK = StatusFlags.WATCHDOG_TRIPPED | StatusFlags.ADC_OVERRANGE | StatusFlags.ENCODER_ERROR
"""Latched faults: any of them forces the actuator to zero until a COMMAND with CLEAR_FAULT."""


class CommandFlags(IntFlag):
    """COMMAND.flags (u8)."""

    ENABLE = 1 << 0  # drive the actuator; clear: the device outputs zero
    CLEAR_FAULT = 1 << 1  # clear latched faults; output is zero on the tick that applies it


class ResetCause(IntEnum):
    """HelloAck.reset_cause (u8): what started the firmware that answers, read from the MCU's reset flags."""

    UNKNOWN = 0  # no flag the firmware knows (or the target cannot tell)
    POWER_ON = 1  # power-on or brown-out of the supply
    PIN = 2  # the reset pin (the board's button, a debugger)
    WATCHDOG = 3  # the hardware watchdog: the firmware hung (or stopped refreshing it)
    SOFTWARE = 4  # the firmware asked for it (SYSRESETREQ)
    FAULT = 5  # the firmware's fault handler took the drive off and let the watchdog reset it


class ActuatorKind(IntEnum):
    """Physical unit of HelloAck.actuator_full_scale."""

    TORQUE_NM = 0
    VOLTAGE_V = 1


@dataclass(frozen=True, slots=True)
class Hello:
    """Host → device: start of the handshake. ``nonce`` names the session: every COMMAND of it carries it."""

    protocol_version: int
    schema_hash: int
    nonce: int

    TYPE: ClassVar[MsgType] = MsgType.HELLO
    FORMAT: ClassVar[str] = "BII"


@dataclass(frozen=True, slots=True)
class HelloAck:
    """Device → host: identity, rate, channel scaling and why it last reset. Echoes the HELLO nonce.

    The float fields travel as IEEE binary32: a decoded value is the f32 rounding of what was sent.
    """

    protocol_version: int
    schema_hash: int
    nonce: int
    device_id: int
    fw_major: int
    fw_minor: int
    fw_patch: int
    sample_rate_hz: int
    watchdog_ms: int
    theta_rad_per_count: float
    theta_offset_counts: int
    theta_dot_rad_s_per_count: float
    theta_dot_offset_counts: int
    phi_counts_per_rev: int
    actuator_full_scale: float
    actuator_kind: int
    reset_cause: int

    TYPE: ClassVar[MsgType] = MsgType.HELLO_ACK
    FORMAT: ClassVar[str] = "BIIIBBBHHfhfhIfBB"


@dataclass(frozen=True, slots=True)
class Config:
    """Host → device: sample rate and watchdog timeout. Answered by a STATUS."""

    rate_hz: int
    watchdog_ms: int

    TYPE: ClassVar[MsgType] = MsgType.CONFIG
    FORMAT: ClassVar[str] = "HH"


@dataclass(frozen=True, slots=True)
class Command:
    """Host → device: actuator command answering SAMPLE ``seq`` of the session ``session`` (its HELLO's nonce);
    applied at the next tick. A COMMAND of another session is discarded (PROTOCOL.md §6)."""

    session: int
    seq: int
    command: int
    flags: int

    TYPE: ClassVar[MsgType] = MsgType.COMMAND
    FORMAT: ClassVar[str] = "IIhB"


@dataclass(frozen=True, slots=True)
class Stop:
    """Host → device: zero the actuator, stop streaming, return to idle."""

    reason: int

    TYPE: ClassVar[MsgType] = MsgType.STOP
    FORMAT: ClassVar[str] = "B"


@dataclass(frozen=True, slots=True)
class Sample:
    """Device → host: one tick's raw measurements."""

    seq: int
    t_us: int
    theta_adc: int
    theta_dot_adc: int
    phi_count: int
    status: int

    TYPE: ClassVar[MsgType] = MsgType.SAMPLE
    FORMAT: ClassVar[str] = "IIhhiH"


@dataclass(frozen=True, slots=True)
class Status:
    """Device → host: faults, applied configuration and link counters (all counted since the HELLO)."""

    flags: int
    rate_hz: int
    watchdog_ms: int
    crc_errors: int
    frame_errors: int
    frames_rx: int
    last_cmd_seq: int
    uart_overruns: int
    uart_line_errors: int

    TYPE: ClassVar[MsgType] = MsgType.STATUS
    FORMAT: ClassVar[str] = "HHHIIIIII"


Message = Hello | HelloAck | Config | Command | Stop | Sample | Status
MESSAGE_CLASSES: tuple[type[Message], ...] = (Hello, Config, Command, Stop, HelloAck, Sample, Status)


class MsgSpec:
    """Precompiled wire layout of one message class (inner frame = type byte + body + CRC)."""

    __slots__ = (
        "body_size",
        "body_struct",
        "cls",
        "field_names",
        "getter",
        "inner_size",
        "make",
        "struct",
        "type_id",
    )

    def __init__(self, cls: type[Message]) -> None:
        self.cls = cls
        self.type_id = int(cls.TYPE)
        self.field_names = tuple(f.name for f in fields(cls))
        if len(cls.FORMAT) != len(self.field_names):
            raise TypeError(f"{cls.__name__}: FORMAT does not have one code per field")
        self.struct = struct.Struct("<B" + cls.FORMAT)  # type byte + body, no padding
        self.body_struct = struct.Struct("<" + cls.FORMAT)
        self.body_size = self.body_struct.size
        self.inner_size = self.struct.size + 2  # + CRC-16
        if len(self.field_names) == 1:  # attrgetter of one name returns a scalar, not a tuple
            name = self.field_names[0]
            self.getter: Callable[[Any], tuple[Any, ...]] = lambda m: (getattr(m, name),)
        else:
            self.getter = attrgetter(*self.field_names)
        self.make: Callable[..., Message] = cls  # the message from its decoded fields


_SAMPLE_SLOTS = tuple(getattr(Sample, f.name).__set__ for f in fields(Sample))


def _sample(seq: int, t_us: int, theta_adc: int, theta_dot_adc: int, phi_count: int, status: int) -> Sample:
    """``Sample(...)`` for the decoder, once per tick on the host: the fields' slots set directly, as the frozen
    dataclass's ``__init__`` sets them through ``object.__setattr__`` (in about half its time)."""
    s = object.__new__(Sample)
    set_seq, set_t_us, set_theta, set_theta_dot, set_phi, set_status = _SAMPLE_SLOTS
    set_seq(s, seq)
    set_t_us(s, t_us)
    set_theta(s, theta_adc)
    set_theta_dot(s, theta_dot_adc)
    set_phi(s, phi_count)
    set_status(s, status)
    return s


SPECS: dict[int, MsgSpec] = {int(c.TYPE): MsgSpec(c) for c in MESSAGE_CLASSES}
SPECS[MsgType.SAMPLE].make = _sample
SPEC_BY_CLASS: dict[type, MsgSpec] = {s.cls: s for s in SPECS.values()}
MAX_INNER_SIZE = max(s.inner_size for s in SPECS.values())


def schema_text(classes: tuple[type[Message], ...] = MESSAGE_CLASSES) -> str:
    """Canonical text of the message definitions and flag bits (input of the schema hash)."""
    lines = []
    for cls in sorted(classes, key=lambda c: int(c.TYPE)):
        names = ",".join(f"{f.name}:{code}" for f, code in zip(fields(cls), cls.FORMAT, strict=True))
        lines.append(f"msg {int(cls.TYPE):#04x} {cls.TYPE.name} <{cls.FORMAT} {names}")
    for enum in (StatusFlags, CommandFlags, ActuatorKind, ResetCause):
        members = ",".join(f"{m.name}={int(m.value)}" for m in enum)
        lines.append(f"enum {enum.__name__} {members}")
    lines.append("frame cobs+crc16-ccitt-false-be")
    return "\n".join(lines) + "\n"


def compute_schema_hash(classes: tuple[type[Message], ...] = MESSAGE_CLASSES) -> int:
    """First 4 bytes (big-endian) of SHA-256 over :func:`schema_text`."""
    digest = hashlib.sha256(schema_text(classes).encode("ascii")).digest()
    return int.from_bytes(digest[:4], "big")


SCHEMA_HASH = compute_schema_hash()


def actuator_to_counts(u: float, full_scale: float) -> int:
    """Physical actuator command → COMMAND counts, rounded and clamped to ±COMMAND_FULL_SCALE.

    Raises ValueError for a non-finite ``u`` or a non-positive/non-finite ``full_scale``.
    """
    if not (math.isfinite(full_scale) and full_scale > 0.0):
        raise ValueError(f"full_scale must be finite and > 0, got {full_scale!r}")
    if not math.isfinite(u):
        raise ValueError(f"actuator command must be finite, got {u!r}")
    counts = round(u / full_scale * COMMAND_FULL_SCALE)
    return COMMAND_FULL_SCALE if counts > COMMAND_FULL_SCALE else max(counts, -COMMAND_FULL_SCALE)


def wrap_delta(new: int, old: int, bits: int = 32) -> int:
    """Signed difference ``new - old`` of wrapping counters (seq, t_us, phi_count).

    The result lies in (-2**(bits-1), 2**(bits-1)].
    """
    half = 1 << (bits - 1)
    return ((new - old + half - 1) % (1 << bits)) - half + 1


def counts_to_actuator(counts: int, full_scale: float) -> float:
    """COMMAND counts → physical actuator command (inverse of :func:`actuator_to_counts`)."""
    return counts * full_scale / COMMAND_FULL_SCALE
