"""The MCAP log layout shared by the daemon's writer, replay, convert and diagnose.

Every message is JSON with a JSON Schema (Foxglove plots it without plugins).

One time base: every message's ``log_time``, ``publish_time`` and schema ``timestamp`` are the same clock,
the host's wall clock in ns since the Unix epoch, so Foxglove's log-time and header-time modes agree. A
tick's time is its device time (the SAMPLE's µs timestamp, unwrapped) mapped onto the wall clock with the
offset taken at the first SAMPLE after the handshake: ``time_ns = device_ns + device_offset_ns``, recorded
in the "time_base" metadata (written when the first tick arrives). Events carry the host wall clock at the
moment they happened. The tick's own ``t`` field stays device time in seconds (what replay uses).
Logs written before the time base (no "time_base" metadata) have publish_time and the JointStates stamp
in device time since the start; readers use ``t`` and are unaffected.

Channels:
  /furuta/tick    one per control tick: the raw SAMPLE, the SI measurement, the controller's output and
                  the supervisor state it ran in (enough for replay to re-run the same update)
  /furuta/timing  one per tick: period, read/update/write durations, latency, counters
  /furuta/joint_states  foxglove.JointStates-shaped: θ and φ as two joints (position, velocity, effort)
  /furuta/events  foxglove.Log-shaped: supervisor transitions, faults, warnings
  /furuta/compensation  (``--comp adaptive`` runs) one per tick: the online Coulomb estimate fc_hat, N m
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
if ``reset`` is true call Controller.reset(phi) first; then call Controller.update if ``state`` is "balancing" or
"swinging_up", else Controller.hold. With a "calibration" record, θ and φ from the first swinging_up/balancing tick
on are first calibrated (θ = wrap(θ − theta_zero), φ − phi_zero). The logged ``u`` must come out bit-identical.
"""

from __future__ import annotations

from typing import Any

TICK_TOPIC = "/furuta/tick"
TIMING_TOPIC = "/furuta/timing"
JOINT_STATES_TOPIC = "/furuta/joint_states"
EVENTS_TOPIC = "/furuta/events"
COMPENSATION_TOPIC = "/furuta/compensation"

RIG_METADATA = "rig"
RUN_METADATA = "run"
DEVICE_METADATA = "device"
TIME_BASE_METADATA = "time_base"
RIG_ATTACHMENT = "rig.toml"

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
    "state": {"type": "string", "enum": ["idle", "armed", "balancing", "tripped", "calibrating", "swinging_up"]},
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
