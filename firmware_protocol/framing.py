"""Framing: COBS byte stuffing, CRC-16/CCITT-FALSE, frame encode/decode.

Wire frame: ``COBS(type ‖ body ‖ crc16_be) ‖ 0x00`` where ``crc16`` is CRC-16/CCITT-FALSE
(poly 0x1021, init 0xFFFF, no reflection, no final xor) over ``type ‖ body``, appended
big-endian so that the CRC over the whole inner frame is 0 (one C call to check).
"""

from __future__ import annotations

import struct
from binascii import crc_hqx
from enum import IntEnum

from .messages import (
    MAX_INNER_SIZE,
    SPEC_BY_CLASS,
    SPECS,
    Message,
    MsgType,
)

FRAME_DELIMITER = b"\x00"
MAX_FRAME_LEN = MAX_INNER_SIZE + 1
"""Longest valid COBS-encoded frame, without the delimiter (inner frames are < 254 bytes)."""

CRC_INIT = 0xFFFF


class FrameError(ValueError):
    """A frame that must not be acted upon. Subclasses say why."""


class CobsError(FrameError):
    """Invalid COBS stuffing (zero byte inside, or a code byte pointing past the end)."""


class CrcError(FrameError):
    """CRC mismatch: the frame was corrupted or truncated."""


class LengthError(FrameError):
    """Too short to hold type and CRC, or CRC-valid but the wrong size for its type."""


class UnknownTypeError(FrameError):
    """CRC-valid frame with a message type id this protocol version does not define."""


class EncodeError(ValueError):
    """A message field is out of range for its wire type."""


class FrameStatus(IntEnum):
    """Result codes of :func:`try_decode_frame` for rejected frames (0 is never returned)."""

    COBS = 1
    CRC = 2
    LENGTH = 3
    UNKNOWN_TYPE = 4


_ERRORS: dict[int, type[FrameError]] = {
    FrameStatus.COBS: CobsError,
    FrameStatus.CRC: CrcError,
    FrameStatus.LENGTH: LengthError,
    FrameStatus.UNKNOWN_TYPE: UnknownTypeError,
}


def crc16(data: bytes | bytearray, crc: int = CRC_INIT) -> int:
    """CRC-16/CCITT-FALSE of ``data`` (check value for b"123456789" is 0x29B1)."""
    return crc_hqx(data, crc)


def cobs_encode(data: bytes | bytearray) -> bytes:
    """COBS-encode ``data`` (no delimiter). Output contains no zero byte."""
    out = bytearray()
    parts = bytes(data).split(b"\x00")
    last = len(parts) - 1
    for k, part in enumerate(parts):
        while len(part) >= 254:
            out.append(0xFF)
            out += part[:254]
            part = part[254:]
            if not part and k == last:  # data ends with a full block: no final code byte
                return bytes(out)
        out.append(len(part) + 1)
        out += part
    return bytes(out)


def cobs_decode(enc: bytes | bytearray) -> bytes:
    """Decode one COBS frame (no delimiter). Raises CobsError on invalid stuffing."""
    out = _cobs_decode(enc)
    if out is None:
        raise CobsError("invalid COBS stuffing")
    return bytes(out)


def _cobs_decode(enc: bytes | bytearray) -> bytearray | None:
    """COBS decode; None if invalid. Fast path: copy, then zero the code-byte positions."""
    n = len(enc)
    if n == 0 or 0 in enc:
        return None
    if n <= 255:  # no group can follow a 0xFF group: every code byte after the first is a zero
        out = bytearray(enc[1:])  # data byte at enc[k] lands at out[k - 1]
        i = enc[0]
        while i < n:
            out[i - 1] = 0
            i += enc[i]
        return out if i == n else None
    out = bytearray()
    i = 0
    while i < n:
        code = enc[i]
        j = i + code
        if j > n:
            return None
        out += enc[i + 1 : j]
        if code != 0xFF and j < n:
            out.append(0)
        i = j
    return out


_CODE_BYTE = tuple(bytes((n + 1,)) for n in range(254))
"""COBS code byte of a group of n data bytes followed by a zero."""


def _stuff(inner: bytes | bytearray) -> bytes:
    """COBS-encode a short inner frame (< 254 bytes) and append the delimiter."""
    out = b""
    for part in inner.split(b"\x00"):
        out += _CODE_BYTE[len(part)] + part
    return out + b"\x00"


def _frame(inner: bytes) -> bytes:
    inner += crc_hqx(inner, CRC_INIT).to_bytes(2, "big")
    return _stuff(inner)


def encode(msg: Message) -> bytes:
    """Encode a message into a complete wire frame, delimiter included."""
    spec = SPEC_BY_CLASS[type(msg)]
    try:
        inner = spec.struct.pack(spec.type_id, *spec.getter(msg))
    except struct.error as exc:
        raise EncodeError(f"{type(msg).__name__}: {exc}") from None
    return _frame(inner)


_COMMAND_STRUCT = SPECS[MsgType.COMMAND].struct
_COMMAND_TYPE = int(MsgType.COMMAND)


def encode_command(session: int, seq: int, value_counts: int, flags: int) -> bytes:
    """Fast path for the per-tick COMMAND frame (no dataclass): ``session`` is the nonce of the HELLO that started
    the session, ``seq`` the SAMPLE answered (wraps modulo 2**32)."""
    try:
        inner = _COMMAND_STRUCT.pack(_COMMAND_TYPE, session, seq & 0xFFFFFFFF, value_counts, flags)
    except struct.error as exc:
        raise EncodeError(f"Command: {exc}") from None
    return _stuff(inner + crc_hqx(inner, CRC_INIT).to_bytes(2, "big"))  # _frame, inline: once per tick


def try_decode_frame(frame: bytes | bytearray) -> Message | int:
    """Decode one frame (without delimiter); never raises. Returns the message or a FrameStatus."""
    if len(frame) > MAX_FRAME_LEN:
        return FrameStatus.LENGTH
    inner = _cobs_decode(frame)
    if inner is None:
        return FrameStatus.COBS
    if len(inner) < 3:
        return FrameStatus.LENGTH
    if crc_hqx(inner, CRC_INIT):
        return FrameStatus.CRC
    spec = SPECS.get(inner[0])
    if spec is None:
        return FrameStatus.UNKNOWN_TYPE
    if len(inner) != spec.inner_size:
        return FrameStatus.LENGTH
    return spec.make(*spec.body_struct.unpack_from(inner, 1))


def decode_frame(frame: bytes | bytearray) -> Message:
    """Decode one frame given without its 0x00 delimiter. Raises a FrameError subclass."""
    result = try_decode_frame(frame)
    if isinstance(result, int):
        raise _ERRORS[result](f"rejected frame ({FrameStatus(result).name}): {bytes(frame).hex()}")
    return result
