"""What the control process hands to the logger: the tick record layout, and its conversion to the log's
messages (kept import-light, so the logger process starts without loading the controller's dependencies)."""

from __future__ import annotations

from typing import Any

from furuta_rt.io.log_schema import TICK_FIELDS, TIMING_FIELDS, device_time_base

STATE_NAMES: tuple[str, ...] = ("idle", "armed", "balancing", "tripped", "calibrating", "swinging_up", "open_loop")
"""Supervisor state index → name, as logged in /furuta/tick ``state``."""

TICK_RECORD: tuple[str, ...] = (
    "wall_ns", "dev_ns", "seq", "t", "theta_adc", "theta_dot_adc", "phi_count", "status",
    "theta", "theta_dot", "phi", "phi_dot_hat", "u", "u_lin", "u_comp", "saturated", "state", "reset",
    "period_us", "read_us", "update_us", "write_us", "latency_us", "lateness_us",
    "overruns", "seq_gaps", "crc_errors", "dropped", "fc_hat",
)  # fmt: skip
"""Field order of the tuples the loop sends to the logger (``state`` is an index into STATE_NAMES; ``fc_hat``:
the Coulomb level the compensator uses, the online estimate with ``--comp adaptive``)."""

_IDX = {name: i for i, name in enumerate(TICK_RECORD)}
_TICK_KEYS = tuple((k, _IDX["state" if k == "mode" else k]) for k in TICK_FIELDS)  # mode: set by tick_fields
_TIMING_KEYS = tuple((k, _IDX[{"dropped_log_messages": "dropped"}.get(k, k)]) for k in TIMING_FIELDS)
_STATE, _WALL, _DEV = _IDX["state"], _IDX["wall_ns"], _IDX["dev_ns"]


def tick_fields(rec: tuple, mode: str) -> dict[str, Any]:
    """The /furuta/tick message (TICK_FIELDS, in order) of one loop record (records.TICK_RECORD)."""
    tick = {k: rec[i] for k, i in _TICK_KEYS}
    tick["state"] = STATE_NAMES[rec[_STATE]]
    tick["mode"] = mode
    return tick


def timing_fields(rec: tuple) -> dict[str, Any]:
    """The /furuta/timing message (TIMING_FIELDS) of one loop record."""
    return {k: rec[i] for k, i in _TIMING_KEYS}


TIME_BASE_WINDOW_NS = 250_000_000
"""Device time over which the time base's least delayed SAMPLE is sought (0.25 s: the first ticks arrive late while
the daemon starts its logger; the loop hands over a batch early when an event is logged, so a batch is no window)."""


class TimeBase:
    """The device clock → wall clock offset, fixed once for a log: the least delayed SAMPLE (smallest host arrival −
    device time, as furuta_rt.runtime.timing.DeviceClock tracks it) of the first TIME_BASE_WINDOW_NS of ticks. The
    ticks of that window are held until it is full (or ``release`` at the end), then handed on with the offset."""

    def __init__(self, window_ns: int = TIME_BASE_WINDOW_NS) -> None:
        self.window_ns = window_ns
        self.offset_ns: int | None = None
        self.metadata: dict[str, str] = {}
        self._held: list[tuple] = []

    def add(self, batch: list[tuple]) -> list[tuple]:
        """The records ready to be written: all of ``batch`` once the offset is fixed, else none (held)."""
        if self.offset_ns is not None:
            return batch
        self._held.extend(batch)
        if not self._held or self._held[-1][_DEV] - self._held[0][_DEV] < self.window_ns:
            return []
        return self.release()

    def release(self) -> list[tuple]:
        """Fix the offset from the ticks held so far (the run ends before the window is full) and hand them on."""
        held, self._held = self._held, []
        if self.offset_ns is None and held:
            first = min(held, key=lambda r: r[_WALL] - r[_DEV])
            self.offset_ns = first[_WALL] - first[_DEV]
            span = (held[-1][_DEV] - held[0][_DEV]) * 1e-9
            self.metadata = device_time_base(first[_WALL], first[_DEV],
                                             f"the least delayed SAMPLE of the first {span:.2f} s of ticks")
        return held


def record_time_ns(rec: tuple, offset: int) -> int:
    """A tick's time on the log's one time base: its device time mapped to the wall clock."""
    return rec[_DEV] + offset
