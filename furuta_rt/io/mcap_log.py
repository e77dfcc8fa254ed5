"""Writing the MCAP log layout of furuta_rt.io.log_schema.

``LogWriter`` writes the channels (a tick's JSON messages and its /furuta/tick_batch record), metadata and
attachment of the layout; metadata go first, so a log
cut short by a killed run still names its rig and run. ``write_recording_mcap`` turns a Recording (a
CSV, a simulation) into such a log: what it does not know (raw counts, θ̇ when absent, φ̂̇) it
computes and says so in the "run" metadata (``derived``).
"""

from __future__ import annotations

import importlib.metadata
import json
import os
import tempfile
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np
from mcap.data_stream import RecordBuilder
from mcap.records import ChunkIndex
from mcap.writer import CompressionType, Writer

from furuta_rt.config import CompMode, RigConfig
from furuta_rt.errors import UserError
from furuta_rt.io import log_schema as ls
from furuta_rt.io.locks import open_locked_for_writing
from furuta_rt.io.rig_toml import rig_to_toml
from furuta_rt.model.rig import calibration_from_config
from furuta_rt.recording import Recording

PROFILE = "furuta_rt"


def package_version() -> str:
    try:
        return importlib.metadata.version("furuta-rt")
    except importlib.metadata.PackageNotFoundError:  # pragma: no cover - running from a source tree
        return "unknown"


def _dumps(obj: Any) -> bytes:
    return json.dumps(obj, separators=(",", ":")).encode()


def rig_metadata(rig: RigConfig) -> dict[str, str]:
    """The "rig" metadata record: name, TOML text and JSON of the config."""
    return {"name": rig.name, "toml": rig_to_toml(rig), "json": rig.model_dump_json()}


def run_metadata(
    mode: str, gains: list[float] | tuple[float, ...] | np.ndarray, rate_hz: float, **extra: str
) -> dict[str, str]:
    """The "run" metadata record (all values are strings, as MCAP metadata requires)."""
    out = {
        "mode": mode,
        "gains": json.dumps([float(g) for g in gains]),
        "rate_hz": repr(float(rate_hz)),
        "version": package_version(),
    }
    out.update({k: str(v) for k, v in extra.items()})
    return out


ABSOLUTE_AFTER_S = 315_532_800.0  # 1980-01-01 in Unix seconds: later times are taken as absolute


_COMPENSATION = -1  # the /furuta/compensation channel before it is registered (LogWriter._held)


def _ns(seconds: float) -> int:
    return max(0, round(seconds * 1e9))


class _EncodedRecords:
    """Records already encoded: ``write`` puts their bytes into the writer's summary as they are."""

    __slots__ = ("data",)

    def __init__(self, data: bytes) -> None:
        self.data = data

    def write(self, builder: RecordBuilder) -> None:
        builder.write(self.data)


class SpilledChunkIndexes:
    """The MCAP writer's list of ChunkIndex records, each encoded as it comes and kept in an anonymous temporary
    file until ``Writer.finish`` writes them into the summary. Held as objects they grow with the run (a chunk
    index with its per-channel offsets is about half a kilobyte; a 1 kHz log ends about a dozen chunks a second);
    spilled, the logger's memory stays flat and the file is byte for byte the same."""

    def __init__(self) -> None:
        self._file = tempfile.TemporaryFile(prefix="furuta-rt-chunk-index-")  # noqa: SIM115 (closed by close())
        self._count = 0

    def append(self, index: ChunkIndex) -> None:
        builder = RecordBuilder()
        index.write(builder)
        self._file.write(builder.end())
        self._count += 1

    def __len__(self) -> int:
        return self._count

    def __iter__(self) -> Iterator[_EncodedRecords]:
        """All the records as one item (the writer writes them one after another into the summary)."""
        if self._count:
            self._file.seek(0)
            data = self._file.read()
            self._file.seek(0, os.SEEK_END)
            yield _EncodedRecords(data)

    def close(self) -> None:
        self._file.close()


def spill_chunk_indexes(writer: Writer) -> SpilledChunkIndexes | None:
    """Make ``writer`` keep its chunk indexes in a SpilledChunkIndexes (None where this mcap version keeps them
    under another name: the writer then keeps them in memory, as it does by default)."""
    name = "_Writer__chunk_indices"
    if not isinstance(getattr(writer, name, None), list) or getattr(writer, name):
        return None
    spill = SpilledChunkIndexes()
    setattr(writer, name, spill)
    return spill


class LogNotInPlace(UserError):
    """The file a run writes is no longer at its path (deleted or replaced by someone else)."""


class LogWriter:
    """Streaming writer of one log: ``tick``/``timing``/``event`` per record, ``close`` writes the summary."""

    def __init__(
        self,
        path: str | Path,
        rig: RigConfig,
        run: Mapping[str, str],
        device: Mapping[str, str] | None = None,
        *,
        chunk_size: int = 256 * 1024,
        compression: CompressionType = CompressionType.ZSTD,
        exclusive: bool = False,
    ) -> None:
        self.path = Path(path)
        self._fh = open_locked_for_writing(self.path, exclusive=exclusive)
        st = os.fstat(self._fh.fileno())
        self._identity = (st.st_dev, st.st_ino)
        w = Writer(self._fh, chunk_size=chunk_size, compression=compression)
        self._spill = spill_chunk_indexes(w)  # the summary's chunk index on disk until close: memory stays flat
        w.start(profile=PROFILE, library=f"furuta_rt {package_version()}")
        w.add_metadata(ls.RIG_METADATA, rig_metadata(rig))
        w.add_metadata(ls.RUN_METADATA, dict(run))
        w.add_metadata(ls.DEVICE_METADATA, dict(device or {}))
        toml = rig_to_toml(rig).encode()
        w.add_attachment(create_time=0, log_time=0, name=ls.RIG_ATTACHMENT, media_type="application/toml", data=toml)

        def channel(topic: str, schema: dict[str, Any]) -> int:
            sid = w.register_schema(schema["title"], "jsonschema", _dumps(schema))
            return w.register_channel(topic, "json", sid)

        self._channel = channel
        self._compensation: int | None = None  # registered with the first message (adaptive runs only)

        self._tick = channel(ls.TICK_TOPIC, ls.TICK_SCHEMA)
        self._timing = channel(ls.TIMING_TOPIC, ls.TIMING_SCHEMA)
        self._joints = channel(ls.JOINT_STATES_TOPIC, ls.JOINT_STATES_SCHEMA)
        self._events = channel(ls.EVENTS_TOPIC, ls.LOG_SCHEMA)
        self._batch_channel: int | None = None  # /furuta/tick_batch, registered with the first batch
        self._batch: list[bytes] = []  # records of the ticks not yet written
        self._batch_start = (0, 0)  # (time_ns, seq) of the batch's first tick
        self._held: list[tuple[int, int, bytes, int]] = []  # their JSON messages: (channel, time, payload, seq)
        self._writer = w
        self._closed = False

    def metadata(self, name: str, data: Mapping[str, str]) -> None:
        """A metadata record written during the run (e.g. "calibration", once it is taken)."""
        self._writer.add_metadata(name, dict(data))

    def time_base(self, mapping: Mapping[str, str]) -> None:
        """The "time_base" metadata: how the messages' times relate to the device clock (log_schema)."""
        self._writer.add_metadata(ls.TIME_BASE_METADATA, dict(mapping))

    def tick(self, time_ns: int, fields: Mapping[str, Any], timing: Mapping[str, Any] | None = None) -> None:
        """One tick (``fields``: every key of TICK_FIELDS; ``timing``: every key of TIMING_FIELDS): its
        /furuta/tick, /furuta/joint_states and /furuta/timing messages and its /furuta/tick_batch record, all with
        log_time = publish_time = JointStates.timestamp = ``time_ns`` (the one time base). Written in batches of
        up to BATCH_TICKS ticks (and at every flush): the batch message first, then the ticks' JSON messages."""
        seq = int(fields["seq"]) & 0xFFFFFFFF
        if not self._batch:
            self._batch_start = (time_ns, seq)
        self._batch.append(ls.pack_tick(time_ns, fields, timing))
        held = self._held
        held.append((self._tick, time_ns, _dumps(fields), seq))
        held.append((self._joints, time_ns, _dumps(ls.joint_states_message(time_ns, fields)), seq))
        if timing is not None:
            held.append((self._timing, time_ns, _dumps(timing), seq))
        if len(self._batch) >= ls.BATCH_TICKS:
            self._write_batch()

    def _write_batch(self) -> None:
        """The pending batch in a chunk of its own (readers that want only it skip the other chunks undecompressed),
        then the JSON messages of its ticks in the next chunk(s)."""
        w = self._writer
        if self._batch:
            w.flush()
            if self._batch_channel is None:
                sid = w.register_schema("furuta_rt.TickBatch", ls.TICK_BATCH_ENCODING, _dumps(ls.tick_batch_schema()))
                self._batch_channel = w.register_channel(ls.TICK_BATCH_TOPIC, ls.TICK_BATCH_ENCODING, sid)
            time_ns, seq = self._batch_start
            w.add_message(self._batch_channel, time_ns, b"".join(self._batch), time_ns, seq)
            w.flush()
            self._batch.clear()
        if self._held:
            for channel, time_ns, payload, seq in self._held:
                if channel == _COMPENSATION and self._compensation is None:  # registered beside its first message
                    self._compensation = self._channel(ls.COMPENSATION_TOPIC, ls.COMPENSATION_SCHEMA)
                w.add_message(self._compensation if channel == _COMPENSATION else channel, time_ns, payload, time_ns, seq)
            w.flush()
            self._held.clear()

    def compensation(self, time_ns: int, seq: int, fc_hat: float) -> None:
        """One /furuta/compensation message at the tick's time: the compensator's Coulomb level (the adaptive
        estimate), written with the tick's batch."""
        seq &= 0xFFFFFFFF
        self._held.append((_COMPENSATION, time_ns, _dumps({"seq": seq, "fc_hat": fc_hat}), seq))

    def event(self, log_time: int, level: str, message: str, name: str = "furuta_rt") -> None:
        self._write_batch()  # the ticks before it first: the file stays in time order
        body = ls.log_message(log_time, level, message, name)
        self._writer.add_message(self._events, log_time, _dumps(body), log_time)

    def flush(self) -> None:
        """End the chunk in progress and push it to the file (what a kill would otherwise lose)."""
        self._write_batch()
        self._writer.flush()

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._write_batch()
            try:
                self._writer.finish()
            finally:
                if self._spill is not None:
                    self._spill.close()
            self._fh.flush()
            gone = self.not_in_place()
            self._fh.close()
            if gone:
                raise LogNotInPlace(gone)

    def not_in_place(self) -> str | None:
        """Why the file this writer writes is no longer the one at its path (deleted, replaced), or None."""
        try:
            st = os.stat(self.path)
        except OSError:
            return f"the log {self.path} was deleted while the run wrote it; what it held is gone"
        if (st.st_dev, st.st_ino) != self._identity:
            return f"the log {self.path} was replaced by another file while the run wrote it; what the run wrote is gone"
        return None

    def __enter__(self) -> LogWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _column(rec: Recording, name: str) -> np.ndarray | None:
    v = rec.extra.get(name)
    return None if v is None else np.asarray(v)


def write_recording_mcap(
    rec: Recording,
    path: str | Path,
    rig: RigConfig,
    *,
    mode: CompMode | None = None,
    gains: list[float] | np.ndarray | None = None,
    source: str | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> Path:
    """Write ``rec`` as a log of ``rig``: every row a tick in state "balancing" (reset on the first),
    so ``replay`` runs the controller over all of it. u_lin, u_comp, phi_dot_hat come from
    ``rec.extra`` when there; otherwise u_lin = u, u_comp = 0 and φ̂̇ = dφ/dt (central differences);
    a missing θ̇ is dθ/dt. Raw counts are the SI values through the rig's calibration (clipped)."""
    from furuta_rt.controller.controller import design_gains

    n = len(rec)
    if n < 2:
        raise UserError(f"recording has {n} rows; a log needs at least two")
    t = np.asarray(rec.t, dtype=float)
    derived: list[str] = []
    theta_dot = rec.theta_dot
    if theta_dot is None:
        theta_dot = np.gradient(rec.theta, t)
        derived.append("theta_dot")
    phi_dot_hat = _column(rec, "phi_dot_hat")
    if phi_dot_hat is None:
        phi_dot_hat = np.gradient(rec.phi, t)
        derived.append("phi_dot_hat")
    u = np.asarray(rec.u, dtype=float)
    u_lin = _column(rec, "u_lin")
    u_comp = _column(rec, "u_comp")
    if u_lin is None or u_comp is None:
        u_lin, u_comp = u, np.zeros(n)
    saturated = _column(rec, "saturated")
    if saturated is None:
        saturated = np.abs(u) >= rig.actuator.limit
    cal = calibration_from_config(rig)
    mode = mode or rig.compensation.mode
    gains_list = [float(g) for g in (design_gains(rig) if gains is None else gains)]
    run = run_metadata(
        mode, gains_list, rig.control.rate_hz, source=source or str(rec.meta.get("source", "recording")),
        converted="true", derived=",".join(derived),
    )
    t0 = float(t[0])
    # the recording's own times; a mapping that starts the recording at t = 0 gives back its start (an
    # absolute time, e.g. Unix seconds, stays absolute); MCAP times are unsigned
    offset = float(rec.meta.get("t_start", t0)) - t0 if isinstance(rec.meta.get("t_start"), int | float) else 0.0
    if t0 + offset < 0:
        offset = -t0
    with LogWriter(path, rig, run, {"calibration": "computed from the rig config"}) as w:
        w.time_base({"clock": "the recording's time column (s) + offset_ns", "offset_ns": str(_ns(offset)),
                     "absolute": str(t0 + offset > ABSOLUTE_AFTER_S).lower()})
        cols = (t, rec.theta, theta_dot, rec.phi, phi_dot_hat, u, u_lin, u_comp, saturated)
        prev = t0
        for k, (tk, th, thd, ph, phd, uk, ul, uc, sat) in enumerate(zip(*(c.tolist() for c in cols), strict=True)):
            a, b, c, _ = cal.to_counts(th, thd, ph)
            ns = _ns(tk + offset)
            w.tick(ns, {
                "seq": k, "t": tk, "theta_adc": a, "theta_dot_adc": b, "phi_count": c, "status": 0,
                "theta": th, "theta_dot": thd, "phi": ph, "phi_dot_hat": phd,
                "u": uk, "u_lin": ul, "u_comp": uc, "saturated": bool(sat),
                "state": "balancing", "reset": k == 0, "mode": mode,
            }, {
                "seq": k, "period_us": (tk - prev) * 1e6, "read_us": 0.0, "update_us": 0.0, "write_us": 0.0,
                "latency_us": 0.0, "lateness_us": 0.0, "overruns": 0, "seq_gaps": 0, "crc_errors": 0,
                "dropped_log_messages": 0,
            })
            prev = tk
            if progress is not None and k % 8192 == 0:
                progress(k, n)
        w.event(_ns(t0 + offset), "INFO", f"converted from {run['source']}")
    return Path(path)
