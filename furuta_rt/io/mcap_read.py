"""Reading furuta-rt MCAP logs (layout: furuta_rt.io.log_schema) into numpy columns.

One code path reads complete logs and logs left by a killed run: the file's records are read front to back
(pread through a read-ahead window, not a memory map: a mapped file that another program truncates kills its
reader with SIGBUS, where a short read here is one line; each record's opcode and length here, mcap's record
classes for channels, schemas, metadata and attachments); a chunk is used only if it is complete and its CRC
checks (mcap's decompression), and reading stops quietly at a torn end — what came before is kept, with a
warning saying how much.

A chunk's MessageIndex records (which follow it) name its channels: a chunk with none that is wanted is not
even decompressed (in a log with /furuta/tick_batch: the JSON chunks). They also give its messages' offsets:
when those account for every byte of the chunk, only the wanted channels' messages are touched; otherwise (a
torn index, a chunk holding channel or schema records) the chunk's records are walked here one by one (not by
mcap's per-message objects). Ticks and timing come from /furuta/tick_batch (packed records, decoded with one
numpy call) when the log has it, else from the JSON /furuta/tick and /furuta/timing payloads, decoded in
batches. That is what makes replaying a long log fast.
"""

from __future__ import annotations

import gc
import json
import os
import stat
import struct
import tomllib
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from io import BytesIO
from operator import itemgetter
from pathlib import Path
from typing import Any

import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import Attachment, Channel, Chunk, DataEnd, Footer, Metadata, Schema
from mcap.stream_reader import StreamReader, get_chunk_data_stream

from furuta_rt.config import RigConfig, rig_from_dict
from furuta_rt.errors import UserError
from furuta_rt.inputs import regular_input
from furuta_rt.io import log_schema as ls
from furuta_rt.recording import Recording

MCAP_MAGIC = b"\x89MCAP0\r\n"
_MESSAGE, _CHANNEL, _SCHEMA = 0x05, 0x04, 0x03
_RECORD = struct.Struct("<BQ")  # opcode, length
_MESSAGE_HEAD = struct.Struct("<BQHIQQ")  # opcode, length, channel id, sequence, log_time, publish_time
_HEAD = _MESSAGE_HEAD.size
_MESSAGE_START = struct.Struct("<BQH")  # opcode, length, channel id
_FEW_MESSAGES = 32  # a chunk with at most this many messages is checked in plain Python
_INDEX_HEAD = struct.Struct("<HI")  # MessageIndex body: channel id, byte length of its (log_time, offset) pairs
_LENGTH_BYTES = np.arange(1, 9)  # a record's u64 length, after its opcode
_CHANNEL_BYTES = np.arange(9, 11)  # a message record's u16 channel id
_SUPERSEDED = (ls.TICK_TOPIC, ls.TIMING_TOPIC)  # read from /furuta/tick_batch when a log has it
# Errors mcap raises when the bytes end or are not MCAP (short reads surface as struct.error).
_READ_ERRORS = (McapError, struct.error, ValueError, EOFError, MemoryError)


def is_mcap(path: str | Path) -> bool:
    """True if the file starts with the MCAP magic (False for anything but a regular file: a FIFO is never
    opened here, where opening it would block)."""
    try:
        if not stat.S_ISREG(os.stat(path).st_mode):
            return False
        with Path(path).open("rb") as fh:
            return fh.read(len(MCAP_MAGIC)) == MCAP_MAGIC
    except OSError:
        return False


try:  # optional: 3-5x faster JSON decoding (exact floats too); not a dependency
    import orjson as _orjson  # type: ignore[import-not-found]
except ImportError:  # pragma: no cover - depends on the environment
    _orjson = None

_loads = json.loads if _orjson is None else _orjson.loads


def _loads_all(payloads: list[bytes]) -> list[Any]:
    """The JSON values of ``payloads``, decoded as one JSON array (one call per chunk instead of one per
    message: a quarter less time). ValueError if a payload is not exactly one JSON value."""
    try:
        values = _loads(b"[" + b",".join(payloads) + b"]")
    except ValueError:  # json.JSONDecodeError and orjson.JSONDecodeError are ValueErrors
        values = None
    if not isinstance(values, list) or len(values) != len(payloads):
        raise ValueError("a payload is not one JSON value")
    return values


class _Columns:
    """Collects one channel's JSON payloads chunk by chunk and turns them into numpy columns."""

    def __init__(self, fields: dict[str, dict[str, Any]] | None) -> None:
        self.fields = fields
        self.pending: list[bytes] = []
        self.times: list[int] = []
        self.parts: dict[str, list[np.ndarray]] = {k: [] for k in fields or {}}
        self.time_parts: list[np.ndarray] = []
        self.rows: list[dict[str, Any]] = []  # fields is None: keep decoded dicts (events)
        self.bad = 0
        self.missing: set[str] = set()

    bad_what = "are not JSON objects"

    def clear(self) -> None:
        """Forget everything collected (the channel turned out to be superseded)."""
        self.__init__(self.fields)  # type: ignore[misc]

    def _decode(self) -> tuple[list[Any], list[int]]:
        try:
            return _loads_all(self.pending), self.times
        except ValueError:
            rows, times = [], []
            for p, t in zip(self.pending, self.times, strict=True):
                try:
                    rows.append(json.loads(p))
                    times.append(t)
                except ValueError:
                    self.bad += 1
            return rows, times

    def flush(self) -> None:
        if not self.pending:
            return
        rows, times = self._decode()
        self.pending, self.times = [], []
        if self.fields is None:
            for r, t in zip(rows, times, strict=True):
                if isinstance(r, dict):
                    self.rows.append({"log_time": t, **r})
            return
        names = list(self.fields)
        try:
            cols = list(zip(*map(itemgetter(*names), rows), strict=True)) if rows else [() for _ in names]
        except (KeyError, TypeError):
            cols = self._tolerant(rows, names)
        for name, col in zip(names, cols, strict=True):
            self.parts[name].append(_to_array(col, self.fields[name]))
        self.time_parts.append(np.asarray(times, dtype=np.int64))

    def _tolerant(self, rows: list[Any], names: list[str]) -> list[tuple[Any, ...]]:
        dicts = [r if isinstance(r, dict) else {} for r in rows]
        self.bad += sum(1 for r in rows if not isinstance(r, dict))
        for name in names:
            if any(name not in r for r in dicts):
                self.missing.add(name)
        return [tuple(r.get(name) for r in dicts) for name in names]

    def result(self) -> tuple[dict[str, np.ndarray], np.ndarray]:
        self.flush()
        cols = {k: np.concatenate(v) if v else _to_array((), self.fields[k]) for k, v in self.parts.items()}  # type: ignore[index]
        times = np.concatenate(self.time_parts) if self.time_parts else np.zeros(0, dtype=np.int64)
        return cols, times


def _to_array(col: Iterable[Any], spec: dict[str, Any]) -> np.ndarray:
    kind = spec.get("type")
    values = tuple(col)
    try:
        if kind == "number":
            return np.array(values, dtype=float)
        if kind == "integer":
            return np.array(values, dtype=np.int64)
        if kind == "boolean":
            return np.array(values, dtype=bool)
        return np.array(values, dtype=str)
    except (TypeError, ValueError):  # None for a missing field, or a wrong type
        if kind == "number":
            return np.array([v if isinstance(v, int | float) else np.nan for v in values], dtype=float)
        if kind == "integer":
            return np.array([v if isinstance(v, int) else -1 for v in values], dtype=np.int64)
        if kind == "boolean":
            return np.array([bool(v) for v in values], dtype=bool)
        return np.array(["" if v is None else str(v) for v in values], dtype=str)


class _TickBatches:
    """Collects /furuta/tick_batch payloads (log_schema: whole packed records) and turns them into the tick and
    timing columns with one numpy call."""

    bad_what = "are not whole tick records"

    def __init__(self) -> None:
        self.pending: list[bytes] = []
        self.times: list[int] = []
        self.parts: list[bytes] = []
        self.rows: list[dict[str, Any]] = []
        self.bad = 0
        self.missing: set[str] = set()

    def flush(self) -> None:
        size = ls.TICK_BATCH_DTYPE.itemsize
        for payload in self.pending:
            if len(payload) % size:
                self.bad += 1
            else:
                self.parts.append(payload)
        self.pending, self.times = [], []

    def result(self) -> tuple[dict[str, np.ndarray], np.ndarray, dict[str, np.ndarray]]:
        """(tick columns as TICK_FIELDS, the ticks' times in ns, timing columns as TIMING_FIELDS)."""
        self.flush()
        # columns are views into one writable buffer of the records (strided: no copy per column)
        rec = np.frombuffer(bytearray().join(self.parts), dtype=ls.TICK_BATCH_DTYPE)
        ticks: dict[str, np.ndarray] = {}
        for name in ls.TICK_FIELDS:
            col = rec[name]
            if name in ("state", "mode"):
                enum = ls.STATES if name == "state" else ls.MODES
                ticks[name] = np.array([*enum, ""])[np.minimum(col, len(enum))]  # an index past the enum: ""
            else:
                ticks[name] = col
        timing = {k: ticks["seq"].copy() if k == "seq" else rec[k] for k in ls.TIMING_FIELDS}
        return ticks, rec["time_ns"], timing


@dataclass
class _Scan:
    size: int
    want: dict[str, _Columns | _TickBatches]
    channels: dict[int, Channel] = field(default_factory=dict)
    schemas: dict[int, Schema] = field(default_factory=dict)
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    attachments: dict[str, bytes] = field(default_factory=dict)
    by_id: dict[int, _Columns | _TickBatches] = field(default_factory=dict)
    batched: bool = False  # ticks and timing come from /furuta/tick_batch
    batch_problem: str | None = None  # a /furuta/tick_batch this version cannot read
    pending_chunk: _ChunkAt | None = None  # the last chunk, used once its MessageIndex records are read
    source: Any = None  # the file's bytes (a _FileBytes) while it is read
    pending_index: list[bytes] = field(default_factory=list)
    chunks: int = 0
    skipped_chunks: int = 0  # complete chunks holding nothing wanted, not decompressed
    bad_chunks: int = 0
    unknown_channel_messages: int = 0
    footer: bool = False
    data_end: bool = False
    good_end: int = 0  # byte offset after the last record read whole
    problem: str | None = None

    def add_channel(self, ch: Channel) -> None:
        self.channels[ch.id] = ch
        if ch.topic == ls.TICK_BATCH_TOPIC and ch.topic in self.want and not self.batched:
            schema = self.schemas.get(ch.schema_id)
            if ch.message_encoding != ls.TICK_BATCH_ENCODING or schema is None or not ls.tick_batch_layout_matches(schema.data):
                self.batch_problem = (f"{ls.TICK_BATCH_TOPIC} has a record layout this version does not know; ticks read"
                                      f" from {ls.TICK_TOPIC}")
                return
            self.batched = True
            for cid in [cid for cid in self.by_id if self.channels[cid].topic in _SUPERSEDED]:
                self.by_id.pop(cid).clear()  # type: ignore[union-attr]
        col = self.want.get(ch.topic)
        if col is not None and not (self.batched and ch.topic in _SUPERSEDED):
            self.by_id[ch.id] = col

    def finish_chunk(self) -> None:
        """Take the wanted messages out of the pending chunk: none, without decompressing it, when its message
        indexes name only known channels none of which is wanted (a log with /furuta/tick_batch: the JSON chunks,
        log_schema); by its message indexes when they account for all of it; else by walking its records."""
        found, indexes = self.pending_chunk, self.pending_index
        self.pending_chunk, self.pending_index = None, []
        if found is None:
            return
        if self.batched and indexes:
            ids = [_INDEX_HEAD.unpack_from(raw)[0] if len(raw) >= _INDEX_HEAD.size else -1 for raw in indexes]
            if all(ch in self.channels and ch not in self.by_id for ch in ids):
                self.chunks += 1
                self.skipped_chunks += 1
                return
        chunk = found.read(self.source)  # _Shrunk propagates: not a damaged chunk
        try:
            stream, length = get_chunk_data_stream(chunk, validate_crc=True)
            data = stream.read(length)
            if len(data) != found.uncompressed_size:
                raise ValueError("size mismatch")
            offsets = self._indexed(data, indexes)
            if offsets is None:
                self.walk_chunk(data)
            else:
                self._take(data, offsets)
            for col in self.want.values():
                col.flush()
            self.chunks += 1
        except Exception:
            for col in self.want.values():
                col.pending.clear()
                col.times.clear()
            self.bad_chunks += 1

    def _indexed(self, data: bytes, indexes: list[bytes]) -> dict[int, np.ndarray] | None:
        """Channel id → its message offsets in the chunk, if the chunk's MessageIndex records name known channels and
        their messages tile the chunk exactly (so it holds nothing else: no channel or schema record); else None."""
        per: dict[int, np.ndarray] = {}
        for raw in indexes:
            if len(raw) < _INDEX_HEAD.size:
                return None
            ch, nbytes = _INDEX_HEAD.unpack_from(raw)
            if nbytes % 16 or _INDEX_HEAD.size + nbytes > len(raw) or ch not in self.channels or ch in per:
                return None
            per[ch] = np.frombuffer(raw, "<u8", nbytes // 8, _INDEX_HEAD.size)[1::2].astype(np.int64)
        if not per:
            return None
        if sum(len(offs) for offs in per.values()) <= _FEW_MESSAGES:
            return per if self._tiled_few(data, per) else None
        offsets = np.sort(np.concatenate(list(per.values())))
        n = len(data)
        if offsets[0] != 0 or offsets[-1] > n - _HEAD:
            return None
        buf = np.frombuffer(data, np.uint8)
        lengths = buf[offsets[:, None] + _LENGTH_BYTES].view("<u8").ravel()
        ends = offsets + 9 + lengths.astype(np.int64)
        if np.any(buf[offsets] != _MESSAGE) or np.any(lengths < _HEAD - 9) or ends[-1] != n or np.any(ends[:-1] != offsets[1:]):
            return None
        for ch, offs in per.items():
            if np.any(buf[offs[:, None] + _CHANNEL_BYTES].view("<u2").ravel() != ch):
                return None
        return per

    @staticmethod
    def _tiled_few(data: bytes, per: dict[int, np.ndarray]) -> bool:
        """_indexed's check for a chunk of a few messages (a tick batch's), in plain Python: numpy's per-call cost
        would be most of it."""
        pos, n = 0, len(data)
        for off, ch in sorted((off, ch) for ch, offs in per.items() for off in offs.tolist()):
            if off != pos or off > n - _HEAD:
                return False
            op, length, channel = _MESSAGE_START.unpack_from(data, off)
            if op != _MESSAGE or channel != ch or length < _HEAD - 9:
                return False
            pos = off + 9 + length
        return pos == n

    def _take(self, data: bytes, per: dict[int, np.ndarray]) -> None:
        """The wanted channels' payloads at the given message offsets (file order)."""
        unpack_message = _MESSAGE_HEAD.unpack_from
        for col in {id(c): c for c in self.by_id.values()}.values():
            offs = [o for ch, o in per.items() if self.by_id.get(ch) is col]
            if not offs:
                continue
            pending, times = col.pending, col.times
            for off in np.sort(np.concatenate(offs)).tolist():
                _, length, _, _, log_time, _ = unpack_message(data, off)
                pending.append(data[off + _HEAD : off + 9 + length])
                times.append(log_time)

    def walk_chunk(self, data: bytes) -> None:
        """Slice the wanted channels' payloads out of one chunk's records."""
        pos, n = 0, len(data)
        by_id = self.by_id
        unpack_message = _MESSAGE_HEAD.unpack_from
        unpack_record = _RECORD.unpack_from
        while pos < n:
            if data[pos] == _MESSAGE:
                _, length, ch, _, log_time, _ = unpack_message(data, pos)
                col = by_id.get(ch)
                if col is not None:
                    col.pending.append(data[pos + _HEAD : pos + 9 + length])
                    col.times.append(log_time)
                elif ch not in self.channels:
                    self.unknown_channel_messages += 1
            else:
                op, length = unpack_record(data, pos)
                if op in (_CHANNEL, _SCHEMA):
                    stream = ReadDataStream(BytesIO(data[pos + 9 : pos + 9 + length]))
                    if op == _CHANNEL:
                        self.add_channel(Channel.read(stream))
                    else:
                        schema = Schema.read(stream)
                        self.schemas[schema.id] = schema
            pos += 9 + length


_OPCODES = frozenset(int(o) for o in Opcode)


def _valid_opcode(op: int) -> bool:
    """An opcode of the MCAP specification, or one of its user range (0x80-0xFF): what a record can start with."""
    return op in _OPCODES or op >= 0x80


class _LogStreamReader(StreamReader):
    """mcap's StreamReader, skipping MessageIndex records (parsing their entries one by one would cost as
    much as reading the messages); furuta_rt.io.repair copies logs with it."""

    def _read_record(self, opcode: int, length: int) -> Any:
        if not _valid_opcode(opcode):
            raise McapError(f"no MCAP record here (opcode {opcode:#04x})")
        if opcode == Opcode.MESSAGE_INDEX:
            self._stream.read(length)
            return None
        return super()._read_record(opcode, length)


@dataclass(frozen=True, slots=True)
class _ChunkAt:
    """A chunk record found in the file: its header fields and where its (compressed) records lie."""

    message_start_time: int
    message_end_time: int
    uncompressed_size: int
    uncompressed_crc: int
    compression: str
    start: int
    end: int

    def read(self, source: Any) -> Chunk:
        return Chunk(compression=self.compression, data=source[self.start : self.end],
                     message_start_time=self.message_start_time, message_end_time=self.message_end_time,
                     uncompressed_size=self.uncompressed_size, uncompressed_crc=self.uncompressed_crc)


_CHUNK_HEAD = struct.Struct("<QQQII")  # message start/end time, uncompressed size and CRC, compression name length
_U64 = struct.Struct("<Q")
_RECORD_TYPES = {Opcode.CHANNEL: Channel, Opcode.SCHEMA: Schema, Opcode.METADATA: Metadata,
                 Opcode.ATTACHMENT: Attachment, Opcode.DATA_END: DataEnd, Opcode.FOOTER: Footer}


def _parse_record(op: int, source: _FileBytes, start: int, end: int) -> Any:
    """The record with opcode ``op`` whose body is source[start:end]: a _ChunkAt for a chunk (its records are not
    read yet), mcap's record for the kinds a log's reader uses, None for the others (never read)."""
    if op == Opcode.CHUNK:
        at = start + _CHUNK_HEAD.size
        if at > end:
            raise ValueError("a chunk record too short for its header")
        t0, t1, size, crc, name_length = _CHUNK_HEAD.unpack(source[start:at])
        if at + name_length + _U64.size > end:
            raise ValueError("a chunk's compression name runs past the chunk record")
        head = source[at : at + name_length + _U64.size]
        compression = head[:name_length].decode()
        (length,) = _U64.unpack_from(head, name_length)
        data = at + name_length + _U64.size
        if data + length > end:
            raise ValueError("a chunk's records run past the chunk record")
        return _ChunkAt(t0, t1, size, crc, compression, data, data + length)
    kind = _RECORD_TYPES.get(op)
    return None if kind is None else kind.read(ReadDataStream(BytesIO(source[start:end])))


class _Shrunk(Exception):
    """The file ended before the size it had when reading began: another program truncated it."""


class _FileBytes:
    """A file's first ``size`` bytes, sliced like bytes (``source[a:b]``), read with pread through a read-ahead
    window: a record header costs no system call of its own, a chunk nobody wants is never read. A read that
    comes up short raises _Shrunk; that is why this is not a memory map, where touching a page past a truncated
    end is SIGBUS (the reader killed, no message)."""

    WINDOW = 1 << 16  # within the C library's small-allocation range: a larger read costs page faults

    def __init__(self, fd: int, size: int) -> None:
        self.fd, self.size = fd, size
        self._at, self._window = 0, b""

    def _pread(self, start: int, n: int) -> bytes:
        parts, want = [], n
        while want > 0:
            part = os.pread(self.fd, want, start + n - want)
            if not part:
                raise _Shrunk
            parts.append(part)
            want -= len(part)
        return parts[0] if len(parts) == 1 else b"".join(parts)

    def __getitem__(self, where: slice) -> bytes:
        start, stop = where.start, where.stop
        at, window = self._at, self._window
        if at <= start and stop <= at + len(window):
            return window[start - at : stop - at]
        if stop - start >= self.WINDOW:
            return self._pread(start, stop - start)
        self._at, self._window = start, self._pread(start, min(self.WINDOW, self.size - start))
        return self._window[: stop - start]


def _scan(path: Path, want: dict[str, _Columns | _TickBatches], progress: Callable[[int, int], None] | None = None) -> _Scan:
    """Read the file's records front to back (a chunk nobody wants is never read), up to a torn end or the
    footer. A file that shrinks meanwhile is a UserError: what was read may mix two versions of it."""
    regular_input(path, "log")  # a FIFO would block, /dev/zero never ends, a link loop is no file
    try:
        fh = path.open("rb")
        size = os.fstat(fh.fileno()).st_size
    except FileNotFoundError:
        raise UserError(f"log {path} does not exist") from None
    except OSError as err:
        raise UserError(f"cannot read {path}: {err.strerror}") from None
    scan = _Scan(size=size, want=want)
    with fh:
        head = fh.read(len(MCAP_MAGIC))
        if head != MCAP_MAGIC:
            what = "is empty" if not head else "is not an MCAP file (no MCAP magic at the start)"
            raise UserError(f"{path} {what}; give a log written by furuta-rt (or convert a CSV with `furuta-rt convert`)")
        was_enabled = gc.isenabled()
        gc.disable()  # decoding makes many small dicts; the cyclic collector only slows it down
        try:
            scan.source = source = _FileBytes(fh.fileno(), size)
            _scan_records(scan, source, path, progress)
            scan.finish_chunk()
            scan.source = None
            if os.fstat(fh.fileno()).st_size < size:
                raise _Shrunk
        except _Shrunk:
            raise UserError(_shrunk_message(path, size, fh.fileno())) from None
        except OSError as err:
            raise UserError(f"cannot read {path}: {(err.strerror or str(err)).lower()}") from None
        finally:
            if was_enabled:
                gc.enable()
    return scan


def _shrunk_message(path: Path, size: int, fd: int) -> str:
    try:
        now = f"{os.fstat(fd).st_size} bytes"
    except OSError:
        now = "less"
    return (f"log {path} shrank while it was read (from {size} bytes to {now}): another program truncated it or is "
            "rewriting it; nothing read from it was used. Read it again once it is complete")


def _scan_records(scan: _Scan, source: _FileBytes, path: Path, progress: Callable[[int, int], None] | None) -> None:
    size = scan.size
    pos = scan.good_end = len(MCAP_MAGIC)
    while pos < size:
        if size - pos < _RECORD.size:
            scan.problem = "the file ends inside a record's opcode and length"
            return
        op, length = _RECORD.unpack(source[pos : pos + _RECORD.size])
        if not _valid_opcode(op):  # zeros of a sparse file, or garbage: no MCAP record starts like this
            scan.problem = f"no MCAP record at byte {pos} (opcode {op:#04x}); the rest of the file is not MCAP"
            return
        start, end = pos + _RECORD.size, pos + _RECORD.size + length
        if end > size:
            scan.problem = f"a record (opcode {op:#04x}) of {length} bytes runs past the end of the file"
            return
        if op == Opcode.MESSAGE_INDEX:
            if scan.pending_chunk is not None:
                scan.pending_index.append(source[start:end])
        else:
            scan.finish_chunk()
            try:
                rec = _parse_record(op, source, start, end)
            except _READ_ERRORS as err:
                scan.problem = f"{type(err).__name__} {err}".strip()
                return
            _use_record(scan, rec, path)
        pos = scan.good_end = end
        if op == Opcode.CHUNK and progress is not None:
            progress(pos, size)
        if op == Opcode.FOOTER:
            return


def _use_record(scan: _Scan, rec: Any, path: Path) -> None:
    if isinstance(rec, _ChunkAt):
        scan.pending_chunk = rec  # used when its message indexes have been read (finish_chunk)
    elif isinstance(rec, Channel):
        scan.add_channel(rec)
    elif isinstance(rec, Schema):
        scan.schemas[rec.id] = rec
    elif isinstance(rec, Metadata):
        scan.metadata[rec.name] = dict(rec.metadata)
    elif isinstance(rec, Attachment):
        scan.attachments[rec.name] = rec.data
    elif isinstance(rec, DataEnd):
        scan.data_end = True
    elif isinstance(rec, Footer):
        scan.footer = True


@dataclass
class LogData:
    """A furuta-rt log: /furuta/tick columns (TICK_FIELDS), timing columns, events and metadata."""

    path: Path
    ticks: dict[str, np.ndarray]
    tick_log_time: np.ndarray  # host clock, ns
    timing: dict[str, np.ndarray]
    events: list[dict[str, Any]]
    metadata: dict[str, dict[str, str]]
    attachments: dict[str, bytes]
    rig: RigConfig | None
    run: dict[str, Any]  # the "run" metadata, with gains as a list and rate_hz as a float
    recovered: bool  # the file was not closed (no summary): read up to its last complete chunk
    warnings: list[str] = field(default_factory=list)
    tick_batches: bool = False  # ticks and timing were read from /furuta/tick_batch (else the JSON channels)

    @property
    def n_ticks(self) -> int:
        return len(self.ticks["t"])

    @property
    def duration(self) -> float:
        t = self.ticks["t"]
        return float(t[-1] - t[0]) if len(t) > 1 else 0.0

    @property
    def mode(self) -> str | None:
        """The compensation mode the run used (run metadata, else the first balancing tick's)."""
        if "mode" in self.run:
            return str(self.run["mode"])
        balancing = np.flatnonzero(self.ticks["state"] == "balancing")
        return str(self.ticks["mode"][balancing[0]]) if len(balancing) else None

    @property
    def gains(self) -> list[float] | None:
        return self.run.get("gains")

    @property
    def device_offset_ns(self) -> int | None:
        """Wall clock − device clock of the log's time base (log_schema), None for a log written before it
        (its publish_time is device time) or one without a device clock (a converted recording)."""
        try:
            return int(self.metadata.get(ls.TIME_BASE_METADATA, {})["device_offset_ns"])
        except (KeyError, ValueError):
            return None

    @property
    def converted(self) -> bool:
        """The log was converted from a recording (its u is not furuta-rt's controller output)."""
        return self.run.get("converted") == "true"


def _parse_run(meta: dict[str, str], warnings: list[str], path: Path) -> dict[str, Any]:
    run: dict[str, Any] = dict(meta)
    if "gains" in meta:
        try:
            gains = json.loads(meta["gains"])
            if not (isinstance(gains, list) and len(gains) == 4):
                raise ValueError
            run["gains"] = [float(g) for g in gains]
        except (ValueError, TypeError):
            warnings.append(f"{path}: run metadata 'gains' is not a list of four numbers ({meta['gains']!r}); ignored")
            del run["gains"]
    if "rate_hz" in meta:
        try:
            run["rate_hz"] = float(meta["rate_hz"])
        except ValueError:
            del run["rate_hz"]
    return run


def _parse_rig(scan: _Scan, path: Path, warnings: list[str]) -> RigConfig | None:
    meta = scan.metadata.get(ls.RIG_METADATA, {})
    attempts: list[tuple[str, Callable[[], dict]]] = []
    if "json" in meta:
        attempts.append(("rig metadata (json)", lambda: json.loads(meta["json"])))
    if "toml" in meta:
        attempts.append(("rig metadata (toml)", lambda: tomllib.loads(meta["toml"])))
    if ls.RIG_ATTACHMENT in scan.attachments:
        attempts.append((f"attachment {ls.RIG_ATTACHMENT}", lambda: tomllib.loads(scan.attachments[ls.RIG_ATTACHMENT].decode())))
    problems = []
    for source, load in attempts:
        try:
            return rig_from_dict(load(), f"{path}: {source}")
        except UserError as err:
            problems.append(str(err))
        except (ValueError, UnicodeDecodeError) as err:
            problems.append(f"{path}: {source} does not parse: {err}")
        except RecursionError:
            problems.append(f"{path}: {source} is nested too deeply to be a rig")
    if problems:
        warnings.append(problems[0] + "; give the rig with --config")
    else:
        warnings.append(f"{path}: the log names no rig config; give it with --config")
    return None


def _recovery_warning(scan: _Scan, path: Path, ticks: dict[str, np.ndarray]) -> str:
    n = len(ticks["t"])
    span = f", t = {ticks['t'][0]:.3f} … {ticks['t'][-1]:.3f} s" if n else ""
    lost = scan.size - scan.good_end
    why = "its summary is missing" if scan.data_end else "it has no summary (the run was killed?)"
    tail = f"; the last {lost} bytes (an incomplete record) were dropped" if lost > 0 else ""
    return (
        f"{path} was not closed properly, {why}: recovered {n} ticks from {scan.chunks} complete chunks"
        f" ({(ticks['t'][-1] - ticks['t'][0]) if n > 1 else 0.0:.2f} s{span}){tail};"
        f" run `furuta-rt repair {path}` to rewrite it with a summary"
    )


def read_log(
    path: str | Path, *, timing: bool = True, events: bool = True, progress: Callable[[int, int], None] | None = None
) -> LogData:
    """Read a log. Never raises on a torn or damaged log (the warnings say what was recovered); a file
    that is not MCAP at all, or missing, is a UserError. ``progress(bytes_read, file_size)`` per chunk."""
    p = Path(path)
    batches = _TickBatches()
    json_ticks = _Columns(ls.TICK_FIELDS)
    json_timing = _Columns(ls.TIMING_FIELDS)
    want: dict[str, _Columns | _TickBatches] = {ls.TICK_BATCH_TOPIC: batches, ls.TICK_TOPIC: json_ticks}
    if timing:
        want[ls.TIMING_TOPIC] = json_timing
    if events:
        want[ls.EVENTS_TOPIC] = _Columns(None)
    scan = _scan(p, want, progress)
    warnings: list[str] = []
    if scan.batched:
        ticks, tick_times, timing_cols = batches.result()
    else:
        ticks, tick_times = json_ticks.result()
        timing_cols = json_timing.result()[0]
        if scan.batch_problem:
            warnings.append(f"{p}: {scan.batch_problem}")
    if not timing:
        timing_cols = {}
    recovered = not scan.footer
    if recovered:
        warnings.append(_recovery_warning(scan, p, ticks))
    if scan.problem and scan.footer:
        warnings.append(f"{p}: {scan.problem}")
    if scan.bad_chunks:
        warnings.append(f"{p}: {scan.bad_chunks} damaged chunk(s) skipped (CRC or decompression failed)")
    for topic, col in want.items():
        if col.bad:
            warnings.append(f"{p}: {col.bad} message(s) on {topic} {col.bad_what}; skipped")
        if col.missing:
            warnings.append(f"{p}: messages on {topic} lack field(s) {', '.join(sorted(col.missing))}")
    if scan.unknown_channel_messages:
        warnings.append(f"{p}: {scan.unknown_channel_messages} message(s) on unknown channels skipped")
    if not any(ch.topic == ls.TICK_TOPIC for ch in scan.channels.values()) and scan.chunks:
        warnings.append(f"{p}: no {ls.TICK_TOPIC} channel; is this a furuta-rt log?")
    run = _parse_run(scan.metadata.get(ls.RUN_METADATA, {}), warnings, p)
    rig = _parse_rig(scan, p, warnings)
    return LogData(
        path=p, ticks=ticks, tick_log_time=tick_times, timing=timing_cols,
        events=want[ls.EVENTS_TOPIC].rows if events else [], metadata=scan.metadata,
        attachments=scan.attachments, rig=rig, run=run, recovered=recovered, warnings=warnings,
        tick_batches=scan.batched,
    )


def log_to_recording(log: LogData) -> Recording:
    """The log's ticks as a Recording (θ̇ left out when the log derived it); the controller's side in ``extra``."""
    tk = log.ticks
    derived = set(str(log.run.get("derived", "")).split(","))
    extra = {k: tk[k] for k in ("phi_dot_hat", "u_lin", "u_comp") if k not in derived}
    extra["saturated"] = tk["saturated"].astype(float)
    extra["balancing"] = (tk["state"] == "balancing").astype(float)
    meta: dict[str, object] = {"source": str(log.path), "format": "mcap", "recovered": log.recovered}
    if log.rig is not None:
        meta["rig"] = log.rig.name
    if log.mode is not None:
        meta["mode"] = log.mode
    return Recording(
        t=tk["t"], theta=tk["theta"], phi=tk["phi"], u=tk["u"],
        theta_dot=None if "theta_dot" in derived else tk["theta_dot"], extra=extra, meta=meta,
    )


def require_ticks(log: LogData) -> LogData:
    """``log`` if it holds at least one tick, else a UserError: a file cut before its first chunk was
    written (or not a furuta-rt log) has nothing to replay, convert or diagnose."""
    if log.n_ticks == 0:
        how = "cut before its first chunk was written" if log.recovered else f"it has no {ls.TICK_TOPIC} messages"
        raise UserError(f"{log.path}: no complete ticks in this log ({how}); nothing to use")
    return log
