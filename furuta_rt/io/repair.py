"""Rewrite an MCAP file that was not closed (killed run: no summary, torn last chunk) as a complete one.

Everything readable is copied in order — schemas, channels, every message of every complete chunk
(bytes untouched), metadata, attachments — into a new file with chunk indexes and a summary, so indexed
readers (Foxglove, ``mcap.reader.make_reader``) open it. Damaged chunks and the torn tail are dropped.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from mcap.records import Attachment, Channel, Chunk, DataEnd, Footer, Header, Message, Metadata, Schema
from mcap.stream_reader import breakup_chunk
from mcap.writer import Writer

from furuta_rt.errors import UserError
from furuta_rt.inputs import regular_input
from furuta_rt.io.locks import refuse_if_being_written
from furuta_rt.io.mcap_read import _READ_ERRORS, MCAP_MAGIC, _LogStreamReader
from furuta_rt.io.output import refuse_existing, replace_when_done


@dataclass(frozen=True)
class RepairReport:
    source: Path
    output: Path
    messages: int
    chunks: int
    damaged_chunks: int
    span_s: float  # log_time span of the messages kept
    dropped_bytes: int  # unreadable bytes at the end of the source
    was_complete: bool


class _Copier:
    def __init__(self, writer: Writer) -> None:
        self.w = writer
        self.schemas: dict[int, int] = {}
        self.channels: dict[int, int] = {}
        self.messages = 0
        self.first = self.last = None

    def schema(self, s: Schema) -> None:
        if s.id not in self.schemas:
            self.schemas[s.id] = self.w.register_schema(s.name, s.encoding, s.data)

    def channel(self, c: Channel) -> None:
        if c.id not in self.channels:
            schema = self.schemas.get(c.schema_id, 0)
            self.channels[c.id] = self.w.register_channel(c.topic, c.message_encoding, schema, dict(c.metadata))

    def message(self, m: Message) -> None:
        ch = self.channels.get(m.channel_id)
        if ch is None:
            return
        self.w.add_message(ch, m.log_time, m.data, m.publish_time, m.sequence)
        self.messages += 1
        self.first = m.log_time if self.first is None else min(self.first, m.log_time)
        self.last = m.log_time if self.last is None else max(self.last, m.log_time)

    def record(self, r: object) -> None:
        if isinstance(r, Schema):
            self.schema(r)
        elif isinstance(r, Channel):
            self.channel(r)
        elif isinstance(r, Message):
            self.message(r)


_FOOTER_RECORD = 1 + 8 + 20  # opcode, length, summary_start, summary_offset_start, summary_crc


def is_complete(path: str | Path) -> bool:
    """True if the file ends with a footer record and the closing magic (it was closed properly)."""
    p = Path(path)
    size = p.stat().st_size
    if size < 2 * len(MCAP_MAGIC) + _FOOTER_RECORD:
        return False
    with p.open("rb") as fh:
        fh.seek(size - len(MCAP_MAGIC) - _FOOTER_RECORD)
        tail = fh.read()
    return tail[0] == 0x02 and tail[-len(MCAP_MAGIC) :] == MCAP_MAGIC


def _same_file(a: Path, b: Path) -> bool:
    if a.resolve() == b.resolve():
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def repair_log(
    path: str | Path, output: str | Path | None = None, *, backup: bool = True, force: bool = False
) -> RepairReport:
    """Rewrite ``path`` with a summary, to ``output`` or in place (the original kept as ``<name>.bak``
    when ``backup``; an ``output`` that is ``path`` itself counts as in place). A complete file is left
    alone unless ``force``; an existing ``output`` (or, in place, ``<name>.bak``: the original an earlier
    repair kept) is replaced only with ``force``. Nothing is replaced
    or deleted unless the rewrite succeeded: a log with nothing recoverable leaves every file as it was."""
    real = regular_input(path, "log")
    src = real if Path(path).is_symlink() else Path(path)  # a link: the file it names is repaired, its .bak beside it
    refuse_if_being_written(src, "log")
    with src.open("rb") as fh:
        if fh.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
            raise UserError(f"{src} is not an MCAP file (no MCAP magic at the start); nothing to repair")
    if is_complete(src) and not force:
        return RepairReport(src, src, 0, 0, 0, 0.0, 0, True)
    in_place = output is None or _same_file(src, Path(output))
    bak = src.with_name(src.name + ".bak")
    if not in_place:
        refuse_existing(output, force=force, flag="-o")  # type: ignore[arg-type]
    elif backup:
        refuse_existing(bak, force=force, flag="the backup")  # an earlier repair's: the original of that one
    dst = src if in_place else Path(output)  # type: ignore[arg-type]
    with replace_when_done(dst, overwrite=in_place or force, flag="-o") as tmp:
        report = _copy_complete_chunks(src, tmp, dst)
        if report.messages == 0 and not report.was_complete:
            raise UserError(f"{src}: no complete chunk in this MCAP file (cut before its first chunk was written); "
                            f"nothing to repair, {src} left as it was")
        if in_place and backup:
            os.replace(src, bak)
    return report


def _copy_complete_chunks(src: Path, tmp: Path, dst: Path) -> RepairReport:
    """Every complete chunk, metadata and attachment of ``src`` into a complete MCAP file ``tmp`` (the
    report names ``dst``, where it goes when done)."""
    size = src.stat().st_size
    chunks = damaged = good_end = 0
    complete = in_summary = False
    with src.open("rb") as fh, tmp.open("wb") as out:
        records = _LogStreamReader(fh, emit_chunks=True, record_size_limit=max(size, 1)).records
        try:
            first = next(records)
        except (StopIteration, *_READ_ERRORS):
            first = None
        header = first if isinstance(first, Header) else Header(profile="", library="")
        writer = Writer(out)
        writer.start(profile=header.profile, library=header.library or "furuta_rt repair")
        copier = _Copier(writer)
        while True:
            try:
                rec = next(records)
            except (StopIteration, *_READ_ERRORS):
                break
            good_end = fh.tell()
            complete = complete or isinstance(rec, Footer)
            in_summary = in_summary or isinstance(rec, DataEnd)
            if in_summary:
                continue
            if isinstance(rec, Chunk):
                try:
                    inner = breakup_chunk(rec, validate_crc=True)
                except Exception:
                    damaged += 1
                    continue
                chunks += 1
                for r in inner:
                    copier.record(r)
            elif isinstance(rec, Metadata):
                writer.add_metadata(rec.name, dict(rec.metadata))
            elif isinstance(rec, Attachment):
                writer.add_attachment(rec.create_time, rec.log_time, rec.name, rec.media_type, rec.data)
            else:
                copier.record(rec)
        writer.finish()
    dropped = 0 if complete else size - good_end  # a closed file ends with its magic, which is no record
    return RepairReport(src, dst, copier.messages, chunks, damaged, _span(copier), dropped, complete)


def _span(c: _Copier) -> float:
    return (c.last - c.first) / 1e9 if c.first is not None and c.last is not None else 0.0
