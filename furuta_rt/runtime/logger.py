"""The MCAP logger: its own process, fed tick batches through a bounded queue by the control loop.

Writes exactly the layout of furuta_rt.io.log_schema: JSON messages with JSON Schemas on
/furuta/tick, /furuta/timing, /furuta/joint_states (foxglove.JointStates) and /furuta/events
(foxglove.Log); metadata "rig", "run", "device"; the attachment "rig.toml". Chunks are zstd
compressed and flushed about every second (mcap ≥ 1.6 ``Writer.flush``), so a killed run leaves a
file a stream reader can read up to its last second. Compression and JSON encoding happen here,
never in the control process (their GIL time would make the loop late).

Queue items (from the control process):
    ("ticks", [tuple in loop.TICK_RECORD order, ...])
    ("event", (wall_ns, level, message))
    ("metadata", name, {str: str})
    ("close", summary_text)
"""

from __future__ import annotations

import json
import multiprocessing
import queue
import signal
import sys
import time
from dataclasses import dataclass, field
from typing import Any, BinaryIO

from mcap.writer import CompressionType, Writer

from furuta_rt.io.log_schema import (
    EVENTS_TOPIC,
    JOINT_STATES_SCHEMA,
    JOINT_STATES_TOPIC,
    LOG_LEVELS,
    LOG_SCHEMA,
    RIG_ATTACHMENT,
    RIG_METADATA,
    RUN_METADATA,
    TICK_FIELDS,
    TICK_SCHEMA,
    TICK_TOPIC,
    TIMING_FIELDS,
    TIMING_SCHEMA,
    TIMING_TOPIC,
)
from furuta_rt.runtime.loop import TICK_RECORD
from furuta_rt.runtime.supervisor import STATE_NAMES

_IDX = {name: i for i, name in enumerate(TICK_RECORD)}
_TICK_KEYS = [(k, _IDX.get(k)) for k in TICK_FIELDS]
_TIMING_KEYS = [(k, _IDX[{"dropped_log_messages": "dropped"}.get(k, k)]) for k in TIMING_FIELDS]
_I = _IDX
_COMPRESSION = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}


@dataclass
class LogSetup:
    """Everything the writer needs before the first tick (device metadata comes later, by queue)."""

    path: str
    rig_name: str
    rig_toml: str
    rig_json: str
    run: dict[str, str] = field(default_factory=dict)
    compression: str = "zstd"
    flush_s: float = 1.0


def _stamp(ns: int) -> dict[str, int]:
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


class McapLogWriter:
    """Tick records and events → MCAP. Used by the logger process (and directly by tests)."""

    def __init__(self, setup: LogSetup, stream: BinaryIO | None = None) -> None:
        self.setup = setup
        self._file = stream if stream is not None else open(setup.path, "wb")  # noqa: SIM115 - closed in close()
        self.writer = Writer(self._file, compression=_COMPRESSION[setup.compression], chunk_size=4 * 1024 * 1024)
        self.writer.start(profile="", library="furuta-rt")
        self.channels: dict[str, int] = {}
        for topic, schema in ((TICK_TOPIC, TICK_SCHEMA), (TIMING_TOPIC, TIMING_SCHEMA),
                              (JOINT_STATES_TOPIC, JOINT_STATES_SCHEMA), (EVENTS_TOPIC, LOG_SCHEMA)):
            sid = self.writer.register_schema(name=schema["title"], encoding="jsonschema",
                                              data=json.dumps(schema).encode())
            self.channels[topic] = self.writer.register_channel(topic=topic, message_encoding="json", schema_id=sid)
        self.mode = setup.run.get("mode", "none")
        self.ticks = 0
        self.events = 0
        self._dirty = False
        now = time.time_ns()
        self.writer.add_metadata(RIG_METADATA, {"name": setup.rig_name, "toml": setup.rig_toml, "json": setup.rig_json})
        self.writer.add_metadata(RUN_METADATA, dict(setup.run))
        self.writer.add_attachment(create_time=now, log_time=now, name=RIG_ATTACHMENT, media_type="application/toml",
                                   data=setup.rig_toml.encode())
        self.writer.flush()

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        self.writer.add_metadata(name, {str(k): str(v) for k, v in data.items()})

    def write_ticks(self, batch: list[tuple]) -> None:
        add = self.writer.add_message
        ch_tick, ch_timing, ch_joint = self.channels[TICK_TOPIC], self.channels[TIMING_TOPIC], self.channels[JOINT_STATES_TOPIC]
        dumps = json.dumps
        mode = self.mode
        for rec in batch:
            log_ns, dev_ns, seq = rec[0], rec[1], rec[2]
            tick: dict[str, Any] = {k: rec[i] for k, i in _TICK_KEYS if i is not None}
            tick["state"] = STATE_NAMES[rec[_I["state"]]]
            tick["mode"] = mode
            timing = {k: rec[i] for k, i in _TIMING_KEYS}
            joints = {
                "timestamp": _stamp(log_ns),
                "joints": [
                    {"name": "theta", "position": rec[_I["theta"]], "velocity": rec[_I["theta_dot"]], "effort": 0.0},
                    {"name": "phi", "position": rec[_I["phi"]], "velocity": rec[_I["phi_dot_hat"]], "effort": rec[_I["u"]]},
                ],
            }
            sq = seq & 0xFFFFFFFF
            add(ch_tick, log_time=log_ns, publish_time=dev_ns, sequence=sq, data=dumps(tick).encode())
            add(ch_timing, log_time=log_ns, publish_time=dev_ns, sequence=sq, data=dumps(timing).encode())
            add(ch_joint, log_time=log_ns, publish_time=dev_ns, sequence=sq, data=dumps(joints).encode())
        self.ticks += len(batch)
        self._dirty = True

    def write_event(self, wall_ns: int, level: str, message: str) -> None:
        msg = {"timestamp": _stamp(wall_ns), "level": LOG_LEVELS.get(level, 2), "message": message,
               "name": "furuta-rt", "file": "", "line": 0}
        self.writer.add_message(self.channels[EVENTS_TOPIC], log_time=wall_ns, publish_time=wall_ns,
                                sequence=self.events, data=json.dumps(msg).encode())
        self.events += 1
        self._dirty = True

    def flush(self) -> None:
        """End the chunk in progress and push it to the file (readable if the process dies)."""
        if self._dirty:
            self.writer.flush()
            self._dirty = False

    def close(self) -> None:
        self.writer.finish()
        self._file.close()

    def handle(self, item: tuple) -> bool:
        """Apply one queue item; False on "close"."""
        kind = item[0]
        if kind == "ticks":
            self.write_ticks(item[1])
        elif kind == "event":
            self.write_event(*item[1])
        elif kind == "metadata":
            self.add_metadata(item[1], item[2])
        elif kind == "close":
            if item[1]:
                self.write_event(time.time_ns(), "INFO", item[1])
            return False
        return True


def logger_process(setup: LogSetup, q: Any, ready: Any) -> None:
    """Entry point of the logger process (spawned). Ends on "close" or when the parent dies."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C goes to the whole group: the daemon decides
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    try:
        w = McapLogWriter(setup)
    except OSError as err:
        print(f"furuta-rt logger: cannot write {setup.path}: {err}", file=sys.stderr)
        return
    ready.set()
    parent = multiprocessing.parent_process()
    last_flush = time.monotonic()
    try:
        while True:
            try:
                item = q.get(timeout=0.2)
            except queue.Empty:
                item = None
            except (EOFError, OSError):
                break
            if item is not None and not w.handle(item):
                break
            now = time.monotonic()
            if now - last_flush >= setup.flush_s:
                w.flush()
                last_flush = now
            if item is None and parent is not None and not parent.is_alive():
                w.write_event(time.time_ns(), "ERROR", "the control process ended without closing the log")
                break
    finally:
        w.close()

