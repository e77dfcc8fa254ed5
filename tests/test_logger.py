"""The MCAP logger: the loop's tick records → the furuta_rt.io.log_schema layout, flushed so that a killed
run stays readable, and the logger process fed through a real multiprocessing queue."""

from __future__ import annotations

import json
import multiprocessing
import shutil
import struct
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.stream_reader import StreamReader
from test_run_loop import SimDevice, make_loop

from furuta_rt.config import RigConfig, load_rig
from furuta_rt.controller.controller import Controller
from furuta_rt.io import log_schema as ls
from furuta_rt.io.mcap_log import run_metadata
from furuta_rt.io.mcap_read import read_log
from furuta_rt.replay.core import replay_log
from furuta_rt.runtime.channel import Channel, Flag
from furuta_rt.runtime.logger import LogSetup, TickLog, logger_process
from furuta_rt.runtime.records import TICK_RECORD, TIME_BASE_WINDOW_NS, TimeBase


@pytest.fixture
def rig() -> RigConfig:
    return load_rig("thesis")


def loop_items(rig: RigConfig, seconds: float) -> tuple[list[tuple], int]:
    """Queue items of a simulated run, as the loop hands them to the logger, and its tick count."""
    dev = SimDevice(rig)
    loop, sink = make_loop(rig, dev, duration=seconds)
    r = loop.run()
    return sink.items(), r.ticks


def write_log(path: Path, rig: RigConfig, items: list[tuple], close: bool = True) -> TickLog:
    run = run_metadata("none", Controller.from_rig(rig).gains, rig.control.rate_hz)
    log = TickLog(LogSetup(path=str(path), rig=rig, run=run))
    log.handle(("event", (time.time_ns(), "INFO", "connecting to /dev/pts/9 at 500 Hz")))
    log.handle(("open", {"device_id": "0x4d4f434b", "actuator_full_scale": "2.0"}))
    for item in items:
        log.handle(item)
    if close:
        log.handle(("close", "summary line"))
        log.close()
    return log


def test_layout_foxglove_can_plot(tmp_path: Path, rig: RigConfig) -> None:
    items, n = loop_items(rig, 1.0)
    path = tmp_path / "run.mcap"
    write_log(path, rig, items)
    with open(path, "rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        assert summary is not None
        topics = {ch.topic: ch for ch in summary.channels.values()}
        assert set(topics) == {ls.TICK_TOPIC, ls.TIMING_TOPIC, ls.JOINT_STATES_TOPIC, ls.EVENTS_TOPIC, ls.TICK_BATCH_TOPIC}
        for topic, ch in topics.items():  # Foxglove decodes every channel but the readers' packed tick batch
            schema = summary.schemas[ch.schema_id]
            json_channel = ch.message_encoding == "json" and schema.encoding == "jsonschema"
            assert json_channel == (topic != ls.TICK_BATCH_TOPIC)
        assert summary.schemas[topics[ls.JOINT_STATES_TOPIC].schema_id].name == "foxglove.JointStates"
        assert summary.schemas[topics[ls.EVENTS_TOPIC].schema_id].name == "foxglove.Log"
        counts = {topics_id: c for topics_id, c in summary.statistics.channel_message_counts.items()}
        by_topic = {summary.channels[cid].topic: c for cid, c in counts.items()}
        assert by_topic[ls.TICK_TOPIC] == by_topic[ls.TIMING_TOPIC] == by_topic[ls.JOINT_STATES_TOPIC] == n
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
        assert set(metadata) == {ls.RIG_METADATA, ls.RUN_METADATA, ls.DEVICE_METADATA, ls.TIME_BASE_METADATA}
        assert metadata[ls.DEVICE_METADATA]["device_id"] == "0x4d4f434b"
        (att,) = list(reader.iter_attachments())
        assert att.name == ls.RIG_ATTACHMENT
        first = next(m for _, c, m in reader.iter_messages(topics=[ls.TICK_TOPIC]))
        tick = json.loads(first.data)
        assert list(tick) == list(ls.TICK_FIELDS) and tick["state"] == "armed" and tick["reset"] is True
        joints = json.loads(next(m for _, c, m in reader.iter_messages(topics=[ls.JOINT_STATES_TOPIC])).data)
        assert [j["name"] for j in joints["joints"]] == ["theta", "phi"]
        # the batch records carry exactly what the JSON tick and timing messages carry (decoded here with struct,
        # by the layout in the log's own schema record)
        layout = json.loads(summary.schemas[topics[ls.TICK_BATCH_TOPIC].schema_id].data)
        codes = {"int64": "q", "float64": "d", "bool": "?", "uint8": "B"}
        record = struct.Struct("<" + "".join(codes[f["type"]] for f in layout["fields"]))
        names = [f["name"] for f in layout["fields"]]
        batched = [dict(zip(names, r, strict=True)) for _, _, m in reader.iter_messages(topics=[ls.TICK_BATCH_TOPIC])
                   for r in record.iter_unpack(m.data)]
        ticks = [(m.log_time, json.loads(m.data)) for _, _, m in reader.iter_messages(topics=[ls.TICK_TOPIC])]
        timings = [json.loads(m.data) for _, _, m in reader.iter_messages(topics=[ls.TIMING_TOPIC])]
        assert len(batched) == len(ticks) == len(timings) == n
        for b, (log_time, tick), timing in zip(batched, ticks, timings, strict=True):
            assert b["time_ns"] == log_time
            assert {k: layout["enums"][k][b[k]] if k in layout["enums"] else b[k] for k in tick} == tick
            assert {k: b[k] for k in timing} == timing
    log = read_log(path)
    assert not log.recovered and log.n_ticks == n and log.rig == rig
    messages = [e["message"] for e in log.events]
    assert messages[0].startswith("connecting to"), "events from before the handshake are kept"
    assert any("→ balancing" in m for m in messages) and messages[-1] == "summary line"
    result = replay_log(log)
    assert result.same_config and result.exact and result.n_phi_dot_mismatch == 0


def test_a_killed_run_is_readable_up_to_its_last_flush(tmp_path: Path, rig: RigConfig) -> None:
    """The logger flushes the chunk in progress about every second: a copy of the file taken after a
    flush (the process killed, no summary, no footer) holds every tick written before it."""
    items, n = loop_items(rig, 2.0)
    path = tmp_path / "run.mcap"
    log = write_log(path, rig, items, close=False)
    log.flush()
    torn = tmp_path / "killed.mcap"
    shutil.copyfile(path, torn)
    with open(torn, "ab") as fh:
        fh.write(b"\x05\x99\x00\x00")  # the start of a record the kill cut short
    ticks, channels = 0, {}
    with open(torn, "rb") as fh, pytest.raises(Exception):  # noqa: B017 - a torn end raises something
        for rec in StreamReader(fh, skip_magic=False).records:
            if type(rec).__name__ == "Channel":
                channels[rec.id] = rec.topic
            elif type(rec).__name__ == "Message":
                ticks += channels[rec.channel_id] == ls.TICK_TOPIC
    assert ticks == n
    recovered = read_log(torn)
    assert recovered.recovered and recovered.n_ticks == n
    log.close()


def _record(wall_ns: int, dev_ns: int) -> tuple:
    rec = [0] * len(TICK_RECORD)
    rec[TICK_RECORD.index("wall_ns")], rec[TICK_RECORD.index("dev_ns")] = wall_ns, dev_ns
    return tuple(rec)


def test_the_time_base_is_the_least_delayed_sample_of_its_window_not_of_a_first_batch() -> None:
    """The loop hands a batch over early when it logs an event, so the first batch can be the first tick alone —
    the one that arrives late while the daemon starts. The map waits for 0.25 s of ticks and takes their least
    delayed SAMPLE; ticks are held until then and handed on in order, later batches pass straight through."""
    period, wall0 = 2_000_000, 1_700_000_000_000_000_000
    delay = [2_200_000] + [150_000] * 40 + [40_000] + [120_000] * 200  # ns from the device tick to its arrival
    recs = [_record(wall0 + k * period + d, k * period) for k, d in enumerate(delay)]
    base = TimeBase()
    assert base.add(recs[:1]) == [] and base.offset_ns is None  # the late first tick alone decides nothing
    out, k = [], 1
    while base.offset_ns is None:
        out += base.add(recs[k : k + 50])
        k += 50
    assert out == recs[:k] and recs[k - 1][TICK_RECORD.index("dev_ns")] >= TIME_BASE_WINDOW_NS
    assert base.offset_ns == wall0 + 40_000  # the least delay (tick 41), not the first tick's 2.2 ms
    assert base.metadata["device_offset_ns"] == str(base.offset_ns)
    assert base.add(recs[k:]) == recs[k:] and base.offset_ns == wall0 + 40_000  # fixed once


def test_a_run_shorter_than_the_time_base_window_keeps_every_tick(tmp_path: Path, rig: RigConfig) -> None:
    """0.1 s of ticks (under the time base's 0.25 s window): the ticks held for the map are written at close, on
    the map of the ticks there were."""
    items, n = loop_items(rig, 0.1)
    path = tmp_path / "run.mcap"
    write_log(path, rig, items)
    log = read_log(path)
    assert log.n_ticks == n == 50 and log.device_offset_ns is not None
    assert log.tick_log_time.tolist() == [round(t * 1e9) + log.device_offset_ns for t in log.ticks["t"]]


def test_logger_process_through_a_spawn_queue(tmp_path: Path, rig: RigConfig) -> None:
    """The daemon's channel (a pipe with a feeder thread, no named semaphore) into a spawned logger."""
    items, n = loop_items(rig, 1.0)
    ctx = multiprocessing.get_context("spawn")
    q = Channel(100)
    ready = Flag()
    path = tmp_path / "run.mcap"
    proc = ctx.Process(target=logger_process, args=(LogSetup(path=str(path), rig=rig, run={"mode": "none"}), q, ready))
    proc.start()
    assert ready.wait(60)
    q.put(("open", {"device_id": "1"}))
    for item in items:
        q.put(item)
    q.put(("close", "done"))
    proc.join(60)
    assert proc.exitcode == 0
    log = read_log(path)
    assert not log.recovered and log.n_ticks == n and log.events[-1]["message"] == "done"


def test_channel_is_bounded_never_blocks_and_reports_the_writer_gone() -> None:
    """Channel: put_nowait raises queue.Full once ``maxsize`` items wait (the reader is behind), items
    arrive in order, and the reader's get raises EOFError when the writer's end is gone."""
    import queue as queue_mod

    ch = Channel(3)
    big = b"x" * 200_000  # larger than a pipe's buffer: the feeder blocks on the first one
    ch.put_nowait(big)
    deadline = time.monotonic() + 10.0
    while ch._items.qsize() and time.monotonic() < deadline:  # the feeder took the first item
        time.sleep(0.01)
    for _ in range(3):
        ch.put_nowait(big)
    with pytest.raises(queue_mod.Full):
        ch.put_nowait(big)
    got = [ch.get(timeout=10.0) for _ in range(4)]
    assert got == [big] * 4
    with pytest.raises(queue_mod.Empty):
        ch.get(timeout=0.05)
    ch._writer.close()
    with pytest.raises(EOFError):
        ch.get(timeout=1.0)
