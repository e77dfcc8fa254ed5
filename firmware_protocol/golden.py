"""Golden vectors shared by the Python and the C codec tests.

``python -m firmware_protocol.golden`` rewrites ``vectors/golden.json``;
``python -m firmware_protocol.golden --check`` exits 1 if the file is stale.

File layout (kept line-oriented so the C test driver can parse it without a JSON
library): a header, then one JSON object per line in ``"vectors"``, each with a
``"kind"``:

* ``frame``: a valid message: ``type``/``type_id``, ``values`` (fields in wire order),
  ``fields`` (by name), ``inner`` (type|body|crc hex) and ``frame`` (COBS frame hex,
  without the 0x00 delimiter).
* ``invalid``: a ``frame`` (no delimiter) that must be rejected with ``error``
  (cobs, crc, length, unknown_type).
* ``cobs``: ``raw`` bytes and their COBS ``encoded`` form (no delimiter).
* ``stream``: a byte ``stream`` fed to a stream decoder; ``expect`` lists the frames
  (hex, re-encoded) it must return in order and ``counters`` the final counter values
  in ``COUNTER_ORDER``.
"""

from __future__ import annotations

import json
import random
import struct
import sys
from pathlib import Path
from typing import Any

from .framing import MAX_FRAME_LEN, FrameStatus, cobs_encode, crc16, encode, try_decode_frame
from .messages import (
    MESSAGE_CLASSES,
    PROTOCOL_VERSION,
    SCHEMA_HASH,
    SPEC_BY_CLASS,
    ActuatorKind,
    Command,
    CommandFlags,
    Config,
    Hello,
    HelloAck,
    Message,
    ResetCause,
    Sample,
    Status,
    StatusFlags,
    Stop,
)
from .stream import StreamDecoder

GOLDEN_PATH = Path(__file__).with_name("vectors") / "golden.json"
COUNTER_ORDER = (
    "frames_ok",
    "crc_errors",
    "length_errors",
    "unknown_type",
    "cobs_errors",
    "overlong",
    "resyncs",
    "bytes_discarded",
)
_ERROR_NAMES = {
    FrameStatus.COBS: "cobs",
    FrameStatus.CRC: "crc",
    FrameStatus.LENGTH: "length",
    FrameStatus.UNKNOWN_TYPE: "unknown_type",
}


def f32(x: float) -> float:
    """Round to the nearest IEEE binary32 value (what the wire carries)."""
    return struct.unpack("<f", struct.pack("<f", x))[0]


def _limits(code: str) -> tuple[int, int]:
    bits = 8 * struct.calcsize(code)
    return (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if code.islower() else (0, (1 << bits) - 1)


def _extreme(cls: type[Message], which: int) -> Message:
    """All fields at their minimum (which=0) or maximum (which=1)."""
    vals: list[Any] = []
    for code in cls.FORMAT:
        if code == "f":
            vals.append(f32(-3.4e38) if which == 0 else f32(3.4e38))
        else:
            vals.append(_limits(code)[which])
    return cls(*vals)


def messages() -> list[tuple[str, Message]]:
    """Named messages covering every type, zeros, extremes and typical values."""
    out: list[tuple[str, Message]] = [
        ("hello", Hello(PROTOCOL_VERSION, SCHEMA_HASH, 0x12345678)),
        (
            "hello_ack_typical",
            HelloAck(
                protocol_version=PROTOCOL_VERSION,
                schema_hash=SCHEMA_HASH,
                nonce=0x12345678,
                device_id=0xF0F0_0001,
                fw_major=1,
                fw_minor=2,
                fw_patch=3,
                sample_rate_hz=1000,
                watchdog_ms=20,
                theta_rad_per_count=f32(2 * 3.141592653589793 / 4096),
                theta_offset_counts=-12,
                theta_dot_rad_s_per_count=f32(0.01),
                theta_dot_offset_counts=7,
                phi_counts_per_rev=4096,
                actuator_full_scale=f32(0.25),
                actuator_kind=ActuatorKind.TORQUE_NM,
                reset_cause=ResetCause.WATCHDOG,
            ),
        ),
        ("config_default", Config(rate_hz=1000, watchdog_ms=20)),
        ("command_enable", Command(session=0x12345678, seq=41, command=-16384, flags=CommandFlags.ENABLE)),
        ("command_clear_fault", Command(session=0x9ABCDEF0, seq=0xFFFFFFFF, command=0, flags=CommandFlags.CLEAR_FAULT)),
        ("stop", Stop(reason=0)),
        (
            "sample_typical",
            Sample(
                seq=41,
                t_us=41_000,
                theta_adc=2048,
                theta_dot_adc=-37,
                phi_count=-1_000_000,
                status=StatusFlags.ENABLED | StatusFlags.COMMAND_LATE,
            ),
        ),
        ("sample_minus_one", Sample(0xFFFFFFFF, 0xFFFFFFFF, -1, -1, -1, 0xFFFF)),
        (
            "status_watchdog",
            Status(
                flags=StatusFlags.WATCHDOG_TRIPPED | StatusFlags.CRC_ERROR,
                rate_hz=1000,
                watchdog_ms=20,
                crc_errors=3,
                frame_errors=1,
                frames_rx=123_456,
                last_cmd_seq=123_400,
                uart_overruns=2,
                uart_line_errors=5,
            ),
        ),
    ]
    for cls in MESSAGE_CLASSES:
        spec = SPEC_BY_CLASS[cls]
        out.append((f"{cls.TYPE.name.lower()}_zero", cls(*([0] * len(spec.field_names)))))
        out.append((f"{cls.TYPE.name.lower()}_min", _extreme(cls, 0)))
        out.append((f"{cls.TYPE.name.lower()}_max", _extreme(cls, 1)))
    return out


def _frame_entry(name: str, msg: Message) -> dict[str, Any]:
    spec = SPEC_BY_CLASS[type(msg)]
    wire = encode(msg)
    values = [getattr(msg, f) for f in spec.field_names]
    values = [v if isinstance(v, float) else int(v) for v in values]
    inner = spec.struct.pack(spec.type_id, *values)
    inner += crc16(inner).to_bytes(2, "big")
    return {
        "kind": "frame",
        "name": name,
        "type": msg.TYPE.name,
        "type_id": spec.type_id,
        "values": values,
        "fields": dict(zip(spec.field_names, values, strict=True)),
        "inner": inner.hex(),
        "frame": wire[:-1].hex(),
    }


def _invalid_entries(frames: list[dict[str, Any]]) -> list[dict[str, Any]]:
    sample = bytes.fromhex(next(f["frame"] for f in frames if f["name"] == "sample_typical"))
    inner = bytes.fromhex(next(f["inner"] for f in frames if f["name"] == "sample_typical"))

    def with_crc(body: bytes) -> bytes:
        return cobs_encode(body + crc16(body).to_bytes(2, "big"))

    def flipped(i: int, mask: int) -> bytes:
        b = bytearray(sample)
        b[i] ^= mask
        return bytes(b)

    cases = [
        ("bit_flip_type_byte", flipped(1, 0x10)),
        ("bit_flip_data_byte", flipped(7, 0x01)),
        ("bit_flip_code_byte", flipped(5, 0x10)),
        ("bit_flip_crc_byte", flipped(len(sample) - 1, 0x80)),
        ("truncated", sample[:-1]),
        ("extra_byte", sample + b"\x01"),
        ("cobs_overrun", b"\x05\x01\x02"),
        ("cobs_zero_inside", sample[:3] + b"\x00" + sample[4:]),
        ("empty_inner_cobs", b"\x01"),
        ("too_short", cobs_encode(b"\x82\x00")),
        ("crc_valid_wrong_length", with_crc(inner[:-3])),
        ("crc_valid_unknown_type", with_crc(b"\x7f" + inner[1:-2])),
        ("crc_little_endian", cobs_encode(inner[:-2] + inner[-2:][::-1])),
        ("overlong", bytes([MAX_FRAME_LEN + 1]) + b"\x11" * MAX_FRAME_LEN),
    ]
    out = []
    for name, frame in cases:
        status = try_decode_frame(frame)
        if not isinstance(status, int):
            raise AssertionError(f"invalid vector {name} decodes")
        out.append({"kind": "invalid", "name": name, "frame": frame.hex(), "error": _ERROR_NAMES[status]})
    return out


def _stream_entries(frames: list[dict[str, Any]]) -> list[dict[str, Any]]:
    rng = random.Random(20240503)
    wires = [bytes.fromhex(f["frame"]) + b"\x00" for f in frames]

    def garbage(n: int) -> bytes:
        return bytes(rng.randrange(256) for _ in range(n))

    def flip(w: bytes) -> bytes:
        b = bytearray(w)
        i = rng.randrange(len(b) - 1) if len(b) > 1 else 0
        b[i] ^= 1 << rng.randrange(8)
        return bytes(b)

    streams = {
        "concatenated": b"".join(wires),
        "leading_partial_frame": wires[6][5:] + b"".join(wires[:4]),
        "garbage_between": b"".join(garbage(rng.randrange(1, 40)) + b"\x00" + w for w in wires),
        "garbage_no_delimiter_before": garbage(17).replace(b"\x00", b"\x01") + b"".join(wires[:3]),
        "overlong_then_frames": b"\x07" * 130 + b"\x00" + b"".join(wires[:3]) + b"\x09" * 200 + wires[3],
        "idle_delimiters": b"\x00\x00\x00" + b"\x00".join(wires[:5]) + b"\x00\x00",
        "bit_flips": b"".join((flip(w) if i % 3 == 1 else w) for i, w in enumerate(wires)),
        "truncated_frames": b"".join(w[: len(w) // 2] + b"\x00" + w for w in wires[:6]),
        "random_noise": garbage(600),
    }
    out = []
    for name, data in streams.items():
        dec = StreamDecoder()
        msgs = dec.feed(data)
        out.append(
            {
                "kind": "stream",
                "name": name,
                "stream": data.hex(),
                "expect": [encode(m)[:-1].hex() for m in msgs],
                "counters": [getattr(dec, c) for c in COUNTER_ORDER],
            }
        )
    return out


def _cobs_entries() -> list[dict[str, Any]]:
    """COBS examples (Cheshire & Baker / Wikipedia), incl. the 254-byte group edge cases."""
    rng = random.Random(7)
    cases = [
        ("empty", b""),
        ("zero", b"\x00"),
        ("two_zeros", b"\x00\x00"),
        ("zero_11_zero", b"\x00\x11\x00"),
        ("mixed", bytes.fromhex("11220033")),
        ("no_zero", bytes.fromhex("11223344")),
        ("trailing_zeros", bytes.fromhex("11000000")),
        ("block_254", bytes(range(1, 255))),
        ("zero_then_block_254", bytes(range(0, 255))),
        ("block_255", bytes(range(1, 256))),
        ("block_254_then_zero", bytes(range(2, 256)) + b"\x00"),
        ("block_253_zero_01", bytes(range(3, 256)) + b"\x00\x01"),
        ("random_600", bytes(rng.choice((0, rng.randrange(1, 256))) for _ in range(600))),
        ("random_nonzero_700", bytes(rng.randrange(1, 256) for _ in range(700))),
    ]
    return [
        {"kind": "cobs", "name": name, "raw": raw.hex(), "encoded": cobs_encode(raw).hex()}
        for name, raw in cases
    ]


def build() -> dict[str, Any]:
    """The golden-vector document (deterministic)."""
    frames = [_frame_entry(name, msg) for name, msg in messages()]
    return {
        "format": "furuta-proto-golden/1",
        "protocol_version": PROTOCOL_VERSION,
        "schema_hash": SCHEMA_HASH,
        "counter_order": list(COUNTER_ORDER),
        "vectors": frames + _invalid_entries(frames) + _stream_entries(frames) + _cobs_entries(),
    }


def dumps(doc: dict[str, Any]) -> str:
    """Serialise with one vector per line (the C driver relies on this)."""
    head = {k: v for k, v in doc.items() if k != "vectors"}
    lines = ["{"]
    lines += [f"{json.dumps(k)}: {json.dumps(v)}," for k, v in head.items()]
    lines.append('"vectors": [')
    body = [json.dumps(v) for v in doc["vectors"]]
    lines.append(",\n".join(body))
    lines.append("]")
    lines.append("}")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    """Write (or with --check, verify) vectors/golden.json."""
    args = sys.argv[1:] if argv is None else argv
    text = dumps(build())
    if "--check" in args:
        current = GOLDEN_PATH.read_text() if GOLDEN_PATH.exists() else ""
        if current != text:
            print(f"{GOLDEN_PATH} is stale; run python -m firmware_protocol.golden", file=sys.stderr)
            return 1
        return 0
    GOLDEN_PATH.parent.mkdir(exist_ok=True)
    GOLDEN_PATH.write_text(text)
    print(f"wrote {GOLDEN_PATH}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
