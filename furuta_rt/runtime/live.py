"""The live view: a run's channels served over the Foxglove WebSocket protocol (the ``foxglove-sdk``
package), for Foxglove's "Open connection → Foxglove WebSocket" at ws://127.0.0.1:PORT. Clients asking for either
name of the protocol (``foxglove.sdk.v1``, ``foxglove.websocket.v1``) are served (live_door).

It lives in the logger process and is fed the same queue items as the MCAP writer (the control process
does nothing more for it): /furuta/tick, /furuta/joint_states, /furuta/timing, /furuta/events (and
/furuta/compensation with ``--comp adaptive``) with
the log's schemas and its one time base (log_schema), so a layout made for a log works live and back.
Messages are encoded only while a client is subscribed (``Channel.has_sinks``), and ticks are sent at
most ``MAX_LIVE_HZ`` times a second (every k-th device tick; the log keeps them all; every event is sent):
a plot of the last seconds needs no more, and the 2-core machine the loop shares does not pay for more. The layout shipped with
furuta-rt (``LAYOUT_PATH``, built by ``layout()``) plots θ, φ and u, shows the supervisor state and the
event log.
"""

from __future__ import annotations

import contextlib
import json
import math
import sys
from pathlib import Path
from typing import Any

from furuta_rt.io import log_schema as ls
from furuta_rt.runtime.live_door import SubprotocolDoor
from furuta_rt.runtime.records import TICK_RECORD, TimeBase, record_time_ns, tick_fields, timing_fields

DEFAULT_PORT = 8765
MAX_LIVE_HZ = 250.0
HOST = "127.0.0.1"
LAYOUT_PATH = Path(__file__).with_name("foxglove_layout.json")
_SEQ, _FC = TICK_RECORD.index("seq"), TICK_RECORD.index("fc_hat")
_CHANNELS = (
    (ls.TICK_TOPIC, ls.TICK_SCHEMA),
    (ls.JOINT_STATES_TOPIC, ls.JOINT_STATES_SCHEMA),
    (ls.TIMING_TOPIC, ls.TIMING_SCHEMA),
    (ls.EVENTS_TOPIC, ls.LOG_SCHEMA),
    (ls.COMPENSATION_TOPIC, ls.COMPENSATION_SCHEMA),  # published with --comp adaptive, as in the log
)

try:
    from orjson import dumps as _dumps
except ImportError:  # pragma: no cover - orjson is a dependency
    def _dumps(obj: Any) -> bytes:
        return json.dumps(obj, separators=(",", ":")).encode()


class LiveView:
    """A Foxglove WebSocket server with the log's channels; ``handle`` takes the logger's queue items."""

    def __init__(self, port: int, host: str = HOST) -> None:
        import foxglove

        foxglove.set_log_level("CRITICAL")  # a client that drops its connection is not the run's problem
        self._context = foxglove.Context()
        # the sdk server on a private loopback port; the door on the user's answers both subprotocol names
        self.server = foxglove.start_server(name="furuta-rt", host=HOST, port=0, context=self._context)
        try:
            self.door = SubprotocolDoor(host, port, self.server.port)
        except BaseException:
            self.server.stop()
            raise
        self.port = self.door.port
        self.channels = {
            topic: foxglove.Channel(topic, message_encoding="json", context=self._context,
                                    schema=foxglove.Schema(name=schema["title"], encoding="jsonschema",
                                                           data=json.dumps(schema).encode()))
            for topic, schema in _CHANNELS
        }
        self.mode = "none"
        self.base = TimeBase()  # the log's time base, so live and logged times agree
        self.every = 1  # send every k-th tick (by device seq): set from the run's rate

    def handle(self, item: tuple) -> LiveView:
        """Publish one queue item of the logger (records.TICK_RECORD batches, events, the run's metadata)."""
        kind = item[0]
        if kind == "ticks" and item[1]:
            self.ticks(item[1])
        elif kind == "event":
            self.event(*item[1])
        elif kind == "open" and len(item) > 2 and item[2]:
            run = item[2]
            self.mode = run.get("mode", self.mode)
            with contextlib.suppress(KeyError, ValueError):
                self.every = max(1, math.ceil(float(run["rate_hz"]) / MAX_LIVE_HZ - 1e-9))
        return self

    def ticks(self, batch: list[tuple]) -> None:
        batch = self.base.add(batch)
        if not batch:
            return
        tick_ch, joints_ch, timing_ch, comp_ch = (self.channels[t] for t in (
            ls.TICK_TOPIC, ls.JOINT_STATES_TOPIC, ls.TIMING_TOPIC, ls.COMPENSATION_TOPIC))
        want_tick, want_joints, want_timing = tick_ch.has_sinks(), joints_ch.has_sinks(), timing_ch.has_sinks()
        want_comp = self.mode == "adaptive" and comp_ch.has_sinks()
        if not (want_tick or want_joints or want_timing or want_comp):
            return
        mode, offset, every = self.mode, self.base.offset_ns, self.every
        for rec in batch:
            if rec[_SEQ] % every:
                continue
            ns = record_time_ns(rec, offset)
            tick = tick_fields(rec, mode)
            if want_tick:
                tick_ch.log(_dumps(tick), log_time=ns)
            if want_joints:
                joints_ch.log(_dumps(ls.joint_states_message(ns, tick)), log_time=ns)
            if want_timing:
                timing_ch.log(_dumps(timing_fields(rec)), log_time=ns)
            if want_comp:
                comp_ch.log(_dumps({"seq": rec[_SEQ], "fc_hat": rec[_FC]}), log_time=ns)

    def event(self, wall_ns: int, level: str, message: str) -> None:
        self.channels[ls.EVENTS_TOPIC].log(_dumps(ls.log_message(wall_ns, level, message)), log_time=wall_ns)

    def close(self) -> None:
        self.door.close()
        self.server.stop()


def start_live_view(port: int, host: str = HOST, failed: Any = None) -> LiveView | None:
    """The live view on ``host:port``, or None when it cannot start: ``failed.set(why)`` (a channel.Flag: the run
    says it and stops, as for a port found busy at its start), else one line on stderr (the run goes on)."""
    try:
        return LiveView(port, host)
    except Exception as err:  # the sdk raises its own errors for a busy port; the loop must not care
        why = (err.strerror if isinstance(err, OSError) and err.strerror else str(err)).lower()
        if failed is not None:
            failed.set(why)
        else:
            print(f"furuta-rt: warning: the live view could not start on {host}:{port}: {why}", file=sys.stderr, flush=True)
        return None


def layout() -> dict[str, Any]:
    """The Foxglove layout for a run, live or logged: θ, φ (rad) and u plotted against time, the supervisor
    state, and the event log (foxglove.layouts, the sdk's own layout model)."""
    import foxglove.layouts as fl

    def plot(title: str, *series: tuple[str, str]) -> Any:
        return fl.PlotPanel(title=title, config=fl.PlotConfig(
            paths=[fl.PlotSeries(value=f"{ls.TICK_TOPIC}.{field}", label=label, timestamp_method="receiveTime")
                   for field, label in series]))

    def item(content: Any, proportion: float = 1) -> Any:
        return fl.SplitItem(proportion=proportion, content=content)

    plots = fl.SplitContainer(direction="column", items=[
        item(plot("θ pendulum angle (rad, 0 upright)", ("theta", "θ (rad)"))),
        item(plot("φ arm angle (rad)", ("phi", "φ (rad)"))),
        item(plot("u command (N m; V for a dc_motor rig)", ("u", "u"), ("u_comp", "u_comp (friction compensation)"))),
    ])
    side = fl.SplitContainer(direction="column", items=[
        item(fl.StateTransitionsPanel(title="supervisor state", config=fl.StateTransitionsConfig(
            paths=[fl.StateTransitionsSeries(value=f"{ls.TICK_TOPIC}.state", label="state")]))),
        item(fl.LogPanel(title="events", config=fl.LogConfig(topic_to_render=ls.EVENTS_TOPIC)), proportion=2),
    ])
    return json.loads(fl.Layout(content=fl.SplitContainer(direction="row", items=[item(plots, 2), item(side)])).to_json())


if __name__ == "__main__":  # regenerate the shipped layout: python -m furuta_rt.runtime.live
    LAYOUT_PATH.write_text(json.dumps(layout(), indent=1, ensure_ascii=False) + "\n")
    print(f"wrote {LAYOUT_PATH}")
