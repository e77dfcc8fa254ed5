"""The MCAP log layout shared by the daemon's writer, replay, convert and diagnose.

Every message but /furuta/tick_batch is JSON with a JSON Schema (Foxglove plots it without plugins);
/furuta/tick_batch carries the same ticks as packed binary records for readers (replay, convert, diagnose).

One time base: every message's ``log_time``, ``publish_time`` and schema ``timestamp`` are the same clock,
the host's wall clock in ns since the Unix epoch, so Foxglove's log-time and header-time modes agree. A
tick's time is its device time (the SAMPLE's µs timestamp, unwrapped) mapped onto the wall clock with the
offset of the least delayed SAMPLE (host arrival − device time) of the first 0.25 s of ticks
(furuta_rt.runtime.records.TimeBase): ``time_ns = device_ns + device_offset_ns``, recorded in the "time_base"
metadata. Events carry the host wall clock at the moment they happened (a supervisor transition: the arrival
of the SAMPLE it was decided on). The tick's own ``t`` field stays device time in seconds (what replay uses).
Logs written before the time base (no "time_base" metadata) have publish_time and the JointStates stamp
in device time since the start; readers use ``t`` and are unaffected.

Channels:
  /furuta/tick    one per control tick: the raw SAMPLE, the SI measurement, the controller's output and
                  the supervisor state it ran in (enough for replay to re-run the same update)
  /furuta/timing  one per tick: period, read/update/write durations, latency, counters
  /furuta/joint_states  foxglove.JointStates-shaped: θ and φ as two joints (position, velocity, effort)
  /furuta/events  foxglove.Log-shaped: supervisor transitions, faults, warnings
  /furuta/compensation  (``--comp adaptive`` runs) one per tick: the online Coulomb estimate fc_hat, N m
  /furuta/tick_batch  the ticks again, many per message (up to BATCH_TICKS, ended at each flush): message and
                  schema encoding "furuta_rt.tick_batch", the message is n packed little-endian records of
                  TICK_BATCH_RECORD (no padding, ``TICK_BATCH_DTYPE.itemsize`` bytes each): the tick's time_ns
                  (its log_time), every TICK_FIELDS field ("state", "mode": uint8 indexes into STATES, MODES)
                  and every TIMING_FIELDS field but seq (NaN / -1 where a writer gave no timing). The schema
                  data is JSON naming the fields and their types in order (tick_batch_schema()). log_time =
                  publish_time = the first record's time_ns. A batch is written before the JSON messages of
                  its ticks, so a log cut short keeps every tick its JSON channels kept. Every log furuta-rt
                  writes carries it; readers take ticks and timing from it when a log has it (a few numpy
                  calls per chunk instead of a JSON decode per tick) and from /furuta/tick and /furuta/timing
                  otherwise (older logs, other writers).
Metadata records:
  "rig"     {"name": ..., "toml": <the rig config as TOML text>, "json": <RigConfig JSON>}
  "run"     {"mode": compensation mode, "gains": "[l1,l2,l3,l4]" JSON, "rate_hz": ..., "port": ..., "version": ...}
  "device"  the HELLO_ACK fields (calibration) as strings
  "calibration" (a --swing-up run, written when taken) {"theta_zero": ..., "phi_zero": ..., ...}: the start-up
            calibration (furuta_rt.runtime.calibration); the ticks' theta and phi are the device's readings before it
  "time_base" {"clock": "wall", "device_offset_ns": ..., "device_t0_ns": ..., "wall_t0_ns": ..., "mapped_at": ...}
            (a converted recording: {"clock": ..., "offset_ns": ...}, its own time column plus offset)
Attachment "rig.toml" carries the same config as a file.

Replay rule: for each /furuta/tick in order, build Measurement(t, theta, theta_dot, phi) from the logged SI values;
if ``reset`` is true call Controller.reset(phi) first; then call Controller.update if ``state`` is one of
DRIVEN_STATES ("balancing", "swinging_up", or "open_loop": a hanging experiment, the "experiment" record's plan
driving the arm open loop), else Controller.hold. With a "calibration" record, θ and φ from the first swinging_up/balancing tick
on are first calibrated (θ = wrap(θ − theta_zero), φ − phi_zero). The logged ``u`` must come out bit-identical.
"""

from __future__ import annotations

import json
import struct
from collections.abc import Mapping
from typing import Any

import numpy as np

TICK_TOPIC = "/furuta/tick"
TIMING_TOPIC = "/furuta/timing"
JOINT_STATES_TOPIC = "/furuta/joint_states"
EVENTS_TOPIC = "/furuta/events"
COMPENSATION_TOPIC = "/furuta/compensation"
TICK_BATCH_TOPIC = "/furuta/tick_batch"
TICK_BATCH_ENCODING = "furuta_rt.tick_batch"
BATCH_TICKS = 256  # most ticks per /furuta/tick_batch message

RIG_METADATA = "rig"
RUN_METADATA = "run"
DEVICE_METADATA = "device"
TIME_BASE_METADATA = "time_base"
RIG_ATTACHMENT = "rig.toml"

STATES = ["idle", "armed", "balancing", "tripped", "calibrating", "swinging_up", "open_loop"]  # supervisor states
DRIVEN_STATES = ("balancing", "swinging_up", "open_loop")  # the controller's update drove the actuator
MODES = ["none", "coulomb", "stiction", "lugre", "adaptive"]  # compensation modes (config.CompMode)

_NUM = {"type": "number"}
_INT = {"type": "integer"}

TICK_FIELDS: dict[str, dict[str, Any]] = {
    "seq": _INT,  # device sequence number of the SAMPLE
    "t": _NUM,  # device time, s (unwrapped)
    "theta_adc": _INT,
    "theta_dot_adc": _INT,
    "phi_count": _INT,
    "status": _INT,  # SAMPLE status flags
    "theta": _NUM,  # SI measurement, rad
    "theta_dot": _NUM,  # rad/s
    "phi": _NUM,  # rad
    "phi_dot_hat": _NUM,  # observer estimate, rad/s
    "u": _NUM,  # command sent (N m, or V for dc_motor rigs)
    "u_lin": _NUM,  # L·x part
    "u_comp": _NUM,  # friction compensation part
    "saturated": {"type": "boolean"},
    "state": {"type": "string", "enum": STATES},
    "reset": {"type": "boolean"},  # Controller.reset(phi) was called before this tick's update
    "mode": {"type": "string"},  # compensation mode
}

TIMING_FIELDS: dict[str, dict[str, Any]] = {
    "seq": _INT,
    "period_us": _NUM,  # host time since the previous tick
    "read_us": _NUM,
    "update_us": _NUM,
    "write_us": _NUM,
    "latency_us": _NUM,  # sample (device time) → command written, estimated on the host clock
    "lateness_us": _NUM,  # how late the tick started against its deadline
    "overruns": _INT,  # cumulative
    "seq_gaps": _INT,  # cumulative missing sequence numbers
    "crc_errors": _INT,  # cumulative, from the stream decoder
    "dropped_log_messages": _INT,  # cumulative, ticks the logger queue could not take
}


def _batch_type(name: str, spec: dict[str, Any]) -> str:
    if name in ("state", "mode"):
        return "uint8"
    return {"number": "float64", "integer": "int64", "boolean": "bool"}[spec["type"]]


TICK_BATCH_RECORD: tuple[tuple[str, str], ...] = (
    ("time_ns", "int64"),
    *((k, _batch_type(k, v)) for k, v in TICK_FIELDS.items()),
    *((k, _batch_type(k, v)) for k, v in TIMING_FIELDS.items() if k != "seq"),
)
"""/furuta/tick_batch record: (field, type) in order; types int64 / float64 little-endian, bool and uint8 one byte."""
_NUMPY_TYPES = {"int64": "<i8", "float64": "<f8", "bool": "?", "uint8": "u1"}
TICK_BATCH_DTYPE = np.dtype([(name, _NUMPY_TYPES[kind]) for name, kind in TICK_BATCH_RECORD])  # packed, no padding


_STRUCT_CODES = {"int64": "q", "float64": "d", "bool": "?", "uint8": "B"}
TICK_BATCH_STRUCT = struct.Struct("<" + "".join(_STRUCT_CODES[kind] for _, kind in TICK_BATCH_RECORD))
_TICK_KEYS = tuple(TICK_FIELDS)
_STATE_POS, _MODE_POS = _TICK_KEYS.index("state"), _TICK_KEYS.index("mode")
_STATE_INDEX = {name: i for i, name in enumerate(STATES)}
_MODE_INDEX = {name: i for i, name in enumerate(MODES)}
_TIMING_KEYS = tuple(k for k in TIMING_FIELDS if k != "seq")
_TIMING_MISSING = tuple(float("nan") if TIMING_FIELDS[k]["type"] == "number" else -1 for k in _TIMING_KEYS)


def pack_tick(time_ns: int, tick: Mapping[str, Any], timing: Mapping[str, Any] | None = None) -> bytes:
    """One /furuta/tick_batch record: the tick's time, its /furuta/tick fields and its /furuta/timing fields."""
    values = [tick[k] for k in _TICK_KEYS]
    values[_STATE_POS] = _STATE_INDEX[values[_STATE_POS]]
    values[_MODE_POS] = _MODE_INDEX[values[_MODE_POS]]
    timed = _TIMING_MISSING if timing is None else [timing[k] for k in _TIMING_KEYS]
    return TICK_BATCH_STRUCT.pack(time_ns, *values, *timed)


def tick_batch_schema() -> dict[str, Any]:
    """The schema data of /furuta/tick_batch (JSON): the record layout, for readers in any language."""
    return {
        "title": "furuta_rt.TickBatch",
        "description": "n packed little-endian records, no padding, one per tick; state and mode index the enums",
        "record_size": TICK_BATCH_DTYPE.itemsize,
        "fields": [{"name": name, "type": kind} for name, kind in TICK_BATCH_RECORD],
        "enums": {"state": STATES, "mode": MODES},
    }


def tick_batch_layout_matches(schema_data: bytes) -> bool:
    """Whether a /furuta/tick_batch schema (its data) describes the record layout this version reads."""
    try:
        doc = json.loads(schema_data)
    except ValueError:
        return False
    mine = tick_batch_schema()
    return isinstance(doc, dict) and all(doc.get(k) == mine[k] for k in ("record_size", "fields", "enums"))


def _object_schema(title: str, fields: dict[str, dict[str, Any]]) -> dict[str, Any]:
    return {"title": title, "type": "object", "properties": fields, "required": list(fields)}


COMPENSATION_FIELDS: dict[str, dict[str, Any]] = {
    "seq": _INT,
    "fc_hat": _NUM,  # the Coulomb level the compensator uses this tick (adaptive: the estimate), N m
}

TICK_SCHEMA = _object_schema("furuta_rt.Tick", TICK_FIELDS)
COMPENSATION_SCHEMA = _object_schema("furuta_rt.Compensation", COMPENSATION_FIELDS)
TIMING_SCHEMA = _object_schema("furuta_rt.Timing", TIMING_FIELDS)

# foxglove.JointStates / foxglove.Log shapes (JSON encoding), see https://docs.foxglove.dev/docs/visualization/message-schemas
JOINT_STATES_SCHEMA: dict[str, Any] = {
    "title": "foxglove.JointStates",
    "type": "object",
    "properties": {
        "timestamp": {"type": "object", "properties": {"sec": _INT, "nsec": _INT}},
        "joints": {
            "type": "array",
            "items": {
                "type": "object",
                "properties": {"name": {"type": "string"}, "position": _NUM, "velocity": _NUM, "effort": _NUM},
            },
        },
    },
}
LOG_LEVELS = {"DEBUG": 1, "INFO": 2, "WARNING": 3, "ERROR": 4, "FATAL": 5}
LOG_SCHEMA: dict[str, Any] = {
    "title": "foxglove.Log",
    "type": "object",
    "properties": {
        "timestamp": {"type": "object", "properties": {"sec": _INT, "nsec": _INT}},
        "level": _INT,
        "message": {"type": "string"},
        "name": {"type": "string"},
        "file": {"type": "string"},
        "line": _INT,
    },
}


def _stamp(time_ns: int) -> dict[str, int]:
    return {"sec": time_ns // 1_000_000_000, "nsec": time_ns % 1_000_000_000}


def joint_states_message(time_ns: int, tick: dict[str, Any]) -> dict[str, Any]:
    """The /furuta/joint_states message of one tick (``tick``: TICK_FIELDS): θ and φ as joints, u as φ's effort."""
    return {
        "timestamp": _stamp(time_ns),
        "joints": [
            {"name": "theta", "position": tick["theta"], "velocity": tick["theta_dot"], "effort": 0.0},
            {"name": "phi", "position": tick["phi"], "velocity": tick["phi_dot_hat"], "effort": tick["u"]},
        ],
    }


def log_message(time_ns: int, level: str, message: str, name: str = "furuta_rt") -> dict[str, Any]:
    """The /furuta/events message (foxglove.Log) of one event (``level``: a key of LOG_LEVELS)."""
    return {"timestamp": _stamp(time_ns), "level": LOG_LEVELS[level], "message": message, "name": name,
            "file": "", "line": 0}


def device_time_base(wall_ns: int, device_ns: int, mapped_at: str) -> dict[str, str]:
    """The "time_base" metadata of a log whose device time ``device_ns`` was seen at wall clock ``wall_ns``:
    every message time is ``device_ns + device_offset_ns`` (log_schema)."""
    return {"clock": "wall", "device_offset_ns": str(wall_ns - device_ns), "device_t0_ns": str(device_ns),
            "wall_t0_ns": str(wall_ns), "mapped_at": mapped_at, "rule": "time_ns = device_ns + device_offset_ns"}
