"""Incremental stream decoder: arbitrary byte chunks in, validated messages out."""

from __future__ import annotations

from .framing import MAX_FRAME_LEN, FrameStatus, try_decode_frame
from .messages import Message


class StreamDecoder:
    """Split a byte stream at 0x00 delimiters and decode each candidate frame.

    ``feed`` never raises on any input bytes and only ever returns frames that passed
    COBS, CRC, type and length checks. After garbage it resynchronises at the next
    delimiter. Consecutive delimiters (empty frames) are ignored and not counted.

    Counters:
        frames_ok: messages returned.
        crc_errors / length_errors / unknown_type / cobs_errors: rejected candidate frames.
        overlong: runs of more than ``max_frame_len`` bytes without a delimiter (dropped,
            then bytes are discarded up to the next delimiter).
        resyncs: times a valid frame was decoded after one or more rejected frames.
        bytes_discarded: bytes of rejected and dropped candidates (delimiters not counted).
    """

    __slots__ = (
        "_buf",
        "_lost",
        "_skipping",
        "bytes_discarded",
        "cobs_errors",
        "crc_errors",
        "frames_ok",
        "length_errors",
        "max_frame_len",
        "overlong",
        "resyncs",
        "unknown_type",
    )

    def __init__(self, max_frame_len: int = MAX_FRAME_LEN) -> None:
        self.max_frame_len = max_frame_len
        self._buf = b""
        self._lost = False
        self._skipping = False
        self.frames_ok = 0
        self.crc_errors = 0
        self.length_errors = 0
        self.unknown_type = 0
        self.cobs_errors = 0
        self.overlong = 0
        self.resyncs = 0
        self.bytes_discarded = 0

    @property
    def errors(self) -> int:
        """Total rejected candidate frames (all causes)."""
        return self.crc_errors + self.length_errors + self.unknown_type + self.cobs_errors + self.overlong

    @property
    def pending(self) -> int:
        """Bytes buffered while waiting for a delimiter."""
        return len(self._buf)

    def reset(self) -> None:
        """Drop buffered bytes (e.g. after reopening the port); counters are kept."""
        self._buf = b""
        self._skipping = False

    def feed(self, chunk: bytes | bytearray | memoryview) -> list[Message]:
        """Consume ``chunk`` and return the messages completed by it, in stream order."""
        if type(chunk) is not bytes:
            chunk = bytes(chunk)
        if self._buf:
            chunk = self._buf + chunk
        end = len(chunk) - 1
        if 0 < end <= self.max_frame_len and chunk.find(0) == end and not self._skipping:
            # one whole frame and its delimiter (a device's tick read at once): the loop below, for one part
            self._buf = b""
            msg = try_decode_frame(chunk[:end])
            if isinstance(msg, int):
                self._reject(msg, end)
                return []
            self.frames_ok += 1
            if self._lost:
                self.resyncs += 1
                self._lost = False
            return [msg]
        parts = chunk.split(b"\x00")
        tail = parts.pop()
        out: list[Message] = []
        if parts:
            if self._skipping:  # remainder of an over-long run: discard up to the delimiter
                self.bytes_discarded += len(parts[0])
                parts[0] = b""
                self._skipping = False
            limit = self.max_frame_len
            for part in parts:
                if not part:
                    continue
                if len(part) > limit:
                    self.overlong += 1
                    self.bytes_discarded += len(part)
                    self._lost = True
                    continue
                msg = try_decode_frame(part)
                if isinstance(msg, int):
                    self._reject(msg, len(part))
                    continue
                self.frames_ok += 1
                if self._lost:
                    self.resyncs += 1
                    self._lost = False
                out.append(msg)
        if len(tail) > self.max_frame_len:
            if not self._skipping:
                self.overlong += 1
                self._lost = True
                self._skipping = True
            self.bytes_discarded += len(tail)
            tail = b""
        self._buf = tail
        return out

    def _reject(self, status: int, nbytes: int) -> None:
        if status == FrameStatus.CRC:
            self.crc_errors += 1
        elif status == FrameStatus.LENGTH:
            self.length_errors += 1
        elif status == FrameStatus.UNKNOWN_TYPE:
            self.unknown_type += 1
        else:
            self.cobs_errors += 1
        self.bytes_discarded += nbytes
        self._lost = True

    def counters(self) -> dict[str, int]:
        """Snapshot of all counters."""
        return {
            "frames_ok": self.frames_ok,
            "crc_errors": self.crc_errors,
            "length_errors": self.length_errors,
            "unknown_type": self.unknown_type,
            "cobs_errors": self.cobs_errors,
            "overlong": self.overlong,
            "resyncs": self.resyncs,
            "bytes_discarded": self.bytes_discarded,
        }
