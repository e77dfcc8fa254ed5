"""MCAP logs: the layout round trip, logs of killed runs (torn at any byte), damaged and non-MCAP files,
and `furuta-rt repair` producing a file that mcap's indexed reader opens."""

from __future__ import annotations

import io
import json
import struct
import tomllib
from pathlib import Path

import numpy as np
import pytest
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import StreamReader

from furuta_rt.cli import main
from furuta_rt.config import RigConfig, load_rig, rig_from_dict
from furuta_rt.errors import UserError
from furuta_rt.io import log_schema as ls
from furuta_rt.io.mcap_read import log_to_recording, read_log
from furuta_rt.io.repair import is_complete, repair_log
from furuta_rt.io.rig_toml import rig_to_toml
from furuta_rt.replay.simulate import simulate_log


@pytest.fixture(scope="module")
def rig() -> RigConfig:
    return load_rig("thesis")


@pytest.fixture(scope="module")
def log_path(tmp_path_factory: pytest.TempPathFactory, rig: RigConfig) -> Path:
    """3 s at 500 Hz, a chunk ended every 0.5 s (as the daemon flushes every second)."""
    return simulate_log(tmp_path_factory.mktemp("mcap") / "run.mcap", rig, 3.0, substep_hz=1000, flush_every=0.5)


def independent_tick_counts(data: bytes) -> tuple[int, int]:
    """(/furuta/tick messages, /furuta/tick_batch records) mcap's own StreamReader yields from ``data`` before the
    bytes end."""
    channels: dict[int, str] = {}
    n_json = n_batch = 0
    try:
        for rec in StreamReader(io.BytesIO(data)).records:
            if hasattr(rec, "topic"):
                channels[rec.id] = rec.topic
            if isinstance(rec, Message) and channels.get(rec.channel_id) == ls.TICK_TOPIC:
                n_json += 1
            if isinstance(rec, Message) and channels.get(rec.channel_id) == ls.TICK_BATCH_TOPIC:
                n_batch += len(rec.data) // ls.TICK_BATCH_DTYPE.itemsize
    except (McapError, ValueError, EOFError, struct.error):  # the torn end, as the library reports it
        pass
    return n_json, n_batch


def tick_chunks(path: Path) -> list[tuple[int, int]]:
    """(start, end) byte offsets of the chunks holding /furuta/tick_batch messages, in file order (the summary's)."""
    with path.open("rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None
    (batch_id,) = (cid for cid, ch in summary.channels.items() if ch.topic == ls.TICK_BATCH_TOPIC)
    return sorted((c.chunk_start_offset, c.chunk_start_offset + c.chunk_length) for c in summary.chunk_indexes
                  if batch_id in c.message_index_offsets)


@pytest.mark.parametrize("name", ["thesis", "qube_servo2", "macstepien"])
def test_rig_toml_round_trip(name: str) -> None:
    rig = load_rig(name)
    assert rig_from_dict(tomllib.loads(rig_to_toml(rig))) == rig


def test_log_round_trip(log_path: Path, rig: RigConfig) -> None:
    log = read_log(log_path)
    assert not log.recovered and log.warnings == []
    assert log.n_ticks == 1500 and set(log.ticks) == set(ls.TICK_FIELDS)
    assert log.ticks["seq"].dtype == np.int64 and log.ticks["u"].dtype == float and log.ticks["reset"].dtype == bool
    assert np.array_equal(log.ticks["seq"], np.arange(1500))
    assert np.allclose(np.diff(log.ticks["t"]), 1 / 500)
    assert set(log.timing) == set(ls.TIMING_FIELDS) and len(log.timing["seq"]) == 1500
    assert log.rig == rig
    assert log.gains is not None and len(log.gains) == 4 and log.run["rate_hz"] == 500.0
    assert log.events[0]["message"] == "simulated run started"
    # SI = calibration(counts), as the daemon converts them
    cal = 2 * np.pi / 4096
    assert np.array_equal(log.ticks["phi"], log.ticks["phi_count"] * cal)
    rec = log_to_recording(log)
    assert np.array_equal(rec.u, log.ticks["u"]) and rec.theta_dot is not None
    assert set(rec.extra) >= {"phi_dot_hat", "u_lin", "u_comp"}


def test_torn_log_read_up_to_last_complete_chunk(tmp_path: Path, log_path: Path) -> None:
    data = log_path.read_bytes()
    full = read_log(log_path)
    with log_path.open("rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None
    chunk_ends = sorted(c.chunk_start_offset + c.chunk_length for c in summary.chunk_indexes)
    batch_ends = [end for _, end in tick_chunks(log_path)]
    assert len(batch_ends) == 6  # one batch per flush (0.5 s, 250 ticks), in a chunk of its own
    first_chunk = min(c.chunk_start_offset for c in summary.chunk_indexes)
    mid_chunk = (first_chunk + chunk_ends[0]) // 2
    cuts = sorted({8, 9, 60, first_chunk, mid_chunk, chunk_ends[0], chunk_ends[0] + 1, chunk_ends[2] - 7,
                   *(e + d for e in batch_ends for d in (-1, 0, 1)),
                   *range(100, len(data), len(data) // 23), len(data) - 200, len(data) - 20})
    cut_path = tmp_path / "cut.mcap"
    for cut in cuts:
        cut_path.write_bytes(data[:cut])
        log = read_log(cut_path)  # never raises
        n = log.n_ticks
        assert log.recovered
        assert np.array_equal(log.ticks["u"], full.ticks["u"][:n]) and np.array_equal(log.ticks["seq"], np.arange(n))
        n_json, n_batch = independent_tick_counts(data[:cut])
        assert n == n_batch >= n_json, cut  # every tick the JSON channel kept (Foxglove's view), and no more than whole batches
        assert n == 250 * sum(1 for end in batch_ends if end <= cut), cut
        assert any("furuta-rt repair" in w and f"recovered {n} ticks" in w for w in log.warnings)
        if n:
            assert f"t = 0.000 … {full.ticks['t'][n - 1]:.3f} s" in log.warnings[0]


def test_recovered_span_reaches_the_last_flush(tmp_path: Path, rig: RigConfig) -> None:
    """Killed at any point, the log reads back up to at most one flush period (0.5 s here) before it."""
    path = simulate_log(tmp_path / "run.mcap", rig, 3.0, substep_hz=1000, flush_every=0.5)
    data = path.read_bytes()
    full = read_log(path)
    for frac in np.linspace(0.15, 0.97, 9):
        cut = int(len(data) * frac)
        (tmp_path / "cut.mcap").write_bytes(data[:cut])
        log = read_log(tmp_path / "cut.mcap")
        # the ticks whose chunk the kill interrupted were at most 0.5 s after the last recovered one
        killed_at = full.ticks["t"][min(log.n_ticks + 249, full.n_ticks - 1)]
        assert killed_at - (log.ticks["t"][-1] if log.n_ticks else 0.0) <= 0.5 + 1e-9


def test_damaged_chunk_is_skipped_with_a_warning(tmp_path: Path, log_path: Path) -> None:
    data = bytearray(log_path.read_bytes())
    start, end = tick_chunks(log_path)[1]
    with log_path.open("rb") as fh:
        fh.seek(start)
        chunk = next(iter(StreamReader(fh, skip_magic=True, emit_chunks=True).records))
    assert isinstance(chunk, Chunk)
    at = end - len(chunk.data)  # the chunk's compressed records end the record
    data[at + 100 : at + 140] = bytes(40)  # zero 40 bytes inside the second tick batch's compressed data
    bad = tmp_path / "damaged.mcap"
    bad.write_bytes(bytes(data))
    log = read_log(bad)
    assert any("damaged chunk" in w for w in log.warnings)
    assert log.n_ticks == 1250 and not log.recovered  # that batch's 250 ticks are lost, the others read
    assert np.array_equal(log.ticks["seq"], np.r_[0:250, 500:1500])


@pytest.mark.parametrize(("content", "expected"), [
    (b"", "is empty"),
    (b"t,theta,phi,u\n0,0,0,0\n", "is not an MCAP file"),
    (b"\x89MCA", "is not an MCAP file"),
    (bytes(range(256)) * 8, "is not an MCAP file"),
])
def test_not_mcap_is_a_user_error(tmp_path: Path, content: bytes, expected: str) -> None:
    p = tmp_path / "x.mcap"
    p.write_bytes(content)
    with pytest.raises(UserError, match=expected) as err:
        read_log(p)
    assert "\n" not in str(err.value)


def test_garbage_after_the_magic_reads_as_an_empty_recovered_log(tmp_path: Path) -> None:
    p = tmp_path / "x.mcap"
    p.write_bytes(b"\x89MCAP0\r\n" + bytes(range(256)) * 8)
    log = read_log(p)
    assert log.n_ticks == 0 and log.recovered and log.rig is None
    assert any("--config" in w for w in log.warnings)


def test_repair_writes_an_indexed_file(tmp_path: Path, log_path: Path) -> None:
    data = log_path.read_bytes()
    torn = tmp_path / "killed.mcap"
    torn.write_bytes(data[: int(len(data) * 0.7)])
    before = read_log(torn)
    assert before.recovered and not is_complete(torn)
    out = tmp_path / "fixed.mcap"
    report = repair_log(torn, out)
    assert report.output == out and not report.was_complete and report.dropped_bytes > 0
    with out.open("rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        ticks = [json.loads(m.data) for _, ch, m in reader.iter_messages(topics=[ls.TICK_TOPIC])]
        metadata = {m.name for m in reader.iter_metadata()}
        attachments = {a.name for a in reader.iter_attachments()}
    assert len(ticks) == before.n_ticks and report.messages == summary.statistics.message_count
    assert [t["u"] for t in ticks] == before.ticks["u"].tolist()
    assert metadata >= {ls.RIG_METADATA, ls.RUN_METADATA, ls.DEVICE_METADATA} and ls.RIG_ATTACHMENT in attachments
    after = read_log(out)
    assert not after.recovered and after.warnings == [] and after.rig == before.rig
    assert np.array_equal(after.ticks["u"], before.ticks["u"])


def test_repair_in_place_keeps_a_backup_and_leaves_complete_files_alone(tmp_path: Path, log_path: Path) -> None:
    data = log_path.read_bytes()
    torn = tmp_path / "killed.mcap"
    torn.write_bytes(data[: len(data) // 2])
    assert repair_log(torn).output == torn
    assert is_complete(torn) and (tmp_path / "killed.mcap.bak").read_bytes() == data[: len(data) // 2]
    again = repair_log(torn)
    assert again.was_complete and again.messages == 0


def test_repair_cli(tmp_path: Path, log_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    data = log_path.read_bytes()
    torn = tmp_path / "killed.mcap"
    torn.write_bytes(data[: len(data) * 3 // 4])
    assert main(["repair", str(torn), "-o", str(tmp_path / "out.mcap")]) == 0
    out = capsys.readouterr().out
    assert "complete chunks" in out and "dropped the last" in out
    assert main(["repair", str(log_path)]) == 0
    assert "nothing to repair" in capsys.readouterr().out
    notmcap = tmp_path / "x.csv"
    notmcap.write_text("t,theta\n")
    assert main(["repair", str(notmcap)]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


def test_bad_tick_messages_are_skipped_with_a_warning(tmp_path: Path, rig: RigConfig) -> None:
    """A log of JSON ticks only (as written before /furuta/tick_batch) with a damaged and an incomplete message."""
    from furuta_rt.io.mcap_log import LogWriter, _dumps, run_metadata

    fields = {k: 0 for k in ls.TICK_FIELDS} | {"t": 0.0, "saturated": False, "reset": False, "state": "idle", "mode": "none"}
    path = tmp_path / "odd.mcap"
    with LogWriter(path, rig, run_metadata("none", [1, 2, 3, 4], 500)) as w:
        w._writer.add_message(w._tick, 0, _dumps(fields), 0)
        w._writer.add_message(w._tick, 1, b"{not json", 1)  # a damaged payload
        w._writer.add_message(w._tick, 2, _dumps(fields | {"seq": 2, "t": 0.004}), 2)
        w._writer.add_message(w._tick, 3, json.dumps({"seq": 3, "t": 0.006}).encode(), 3)  # fields missing
    log = read_log(path)
    assert log.ticks["seq"].tolist() == [0, 2, 3] and np.isnan(log.ticks["u"][2])
    assert any("1 message(s) on /furuta/tick are not JSON" in w for w in log.warnings)
    assert any("lack field(s)" in w and "theta" in w for w in log.warnings)


def test_tick_batch_with_a_torn_record_or_an_unknown_layout(tmp_path: Path, rig: RigConfig) -> None:
    """A /furuta/tick_batch message that is not whole records is skipped with a warning (the others read); a batch
    channel whose schema describes another record layout is not used: the JSON ticks are read instead."""
    from furuta_rt.io.mcap_log import LogWriter, run_metadata

    fields = {k: 0 for k in ls.TICK_FIELDS} | {"t": 0.0, "saturated": False, "reset": False, "state": "balancing", "mode": "none"}
    path = tmp_path / "torn_record.mcap"
    with LogWriter(path, rig, run_metadata("none", [1, 2, 3, 4], 500)) as w:
        for k in range(3):
            w.tick(k, fields | {"seq": k, "t": 0.002 * k})
        w.flush()
        w._writer.add_message(w._batch_channel, 3, ls.pack_tick(3, fields | {"seq": 3})[:-1], 3)  # a record cut short
        w.tick(4, fields | {"seq": 4, "t": 0.008})
    log = read_log(path)
    assert log.ticks["seq"].tolist() == [0, 1, 2, 4] and log.ticks["state"].tolist() == ["balancing"] * 4
    assert np.isnan(log.timing["period_us"]).all() and (log.timing["overruns"] == -1).all()  # no timing was given
    assert any(f"1 message(s) on {ls.TICK_BATCH_TOPIC} are not whole tick records" in w for w in log.warnings)

    other = tmp_path / "other_layout.mcap"
    with LogWriter(other, rig, run_metadata("none", [1, 2, 3, 4], 500)) as w:
        sid = w._writer.register_schema("furuta_rt.TickBatch", ls.TICK_BATCH_ENCODING, b'{"record_size": 8, "fields": []}')
        w._batch_channel = w._writer.register_channel(ls.TICK_BATCH_TOPIC, ls.TICK_BATCH_ENCODING, sid)
        w.tick(0, fields)
        w.tick(1, fields | {"seq": 1, "t": 0.002})
    log = read_log(other)
    assert log.ticks["seq"].tolist() == [0, 1]  # from /furuta/tick
    assert any("record layout this version does not know" in w for w in log.warnings)


def _write_ticks(path: Path, rig: RigConfig, n: int, flush_every: int, keep_in_memory: bool = False,
                 during: object = None) -> None:
    from furuta_rt.io.mcap_log import LogWriter, run_metadata

    fields = {k: 0 for k in ls.TICK_FIELDS} | {"t": 0.0, "saturated": False, "reset": False, "state": "balancing",
                                               "mode": "none"}
    with LogWriter(path, rig, run_metadata("none", [1, 2, 3, 4], 1000)) as w:
        if keep_in_memory:  # the mcap writer as it comes: its chunk indexes in a list
            w._writer._Writer__chunk_indices = []  # type: ignore[attr-defined]
        for k in range(n):
            w.tick(k * 1_000_000, fields | {"seq": k, "t": k * 1e-3, "u": 0.001 * (k % 7)})
            if (k + 1) % flush_every == 0:
                w.flush()
                if callable(during):
                    during(k)


def test_chunk_indexes_spilled_to_disk_give_the_same_file(tmp_path: Path, rig: RigConfig) -> None:
    """The log writer keeps the summary's chunk index on disk until close: the file is byte for byte what the mcap
    writer makes with its in-memory list, and the official reader finds every chunk through the summary."""
    spilled, listed = tmp_path / "spilled.mcap", tmp_path / "listed.mcap"
    _write_ticks(spilled, rig, 3000, 50)
    _write_ticks(listed, rig, 3000, 50, keep_in_memory=True)
    assert spilled.read_bytes() == listed.read_bytes()
    with spilled.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics is not None
    assert len(summary.chunk_indexes) == summary.statistics.chunk_count >= 120  # 60 flushes, a batch and JSON each
    assert read_log(spilled).ticks["seq"].tolist() == list(range(3000))


def test_log_writer_memory_does_not_grow_with_the_chunks(tmp_path: Path, rig: RigConfig) -> None:
    """Python heap held by a LogWriter after 300 more flushes (≥ 600 more chunks): the spilled chunk index adds no
    memory per chunk; the in-memory list (the control case) adds hundreds of bytes per chunk."""
    import tracemalloc

    def growth(keep_in_memory: bool) -> float:
        held: dict[int, int] = {}

        def note(k: int) -> None:
            if (k + 1) // 10 in (100, 400):
                held[(k + 1) // 10] = tracemalloc.get_traced_memory()[0]

        tracemalloc.start()
        try:
            _write_ticks(tmp_path / f"m{keep_in_memory}.mcap", rig, 4000, 10, keep_in_memory, during=note)
        finally:
            tracemalloc.stop()
        return (held[400] - held[100]) / 600  # bytes per chunk (two chunks a flush)

    assert growth(keep_in_memory=True) > 200
    assert growth(keep_in_memory=False) < 20
