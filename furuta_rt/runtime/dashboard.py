"""The live dashboard: a rich Live view in its own process, fed ≤ 10 snapshots per second.

Rendering a rich table takes milliseconds of Python; in the control process that time would hold
the GIL and make ticks late, so the loop only drops a small dict into a 2-slot queue (``put_nowait``;
a full queue skips the snapshot) and this process draws it.

What it shows (``Dashboard``): the numbers of the latest snapshot; traces of θ, φ and u over the last
``TRACE_S`` seconds; a line saying what the current state waits for or what ends it (``STATE_HINTS``,
one entry per supervisor state: add yours there); the limit cycle of φ over the last ``LIMIT_CYCLE_S``
seconds (furuta_rt.stats, the detector of the run summary and replay); the log file; "Ctrl-C to stop".
"""

from __future__ import annotations

import math
import multiprocessing
import queue
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from rich.console import Group
from rich.live import Live
from rich.panel import Panel
from rich.table import Table
from rich.text import Text

from furuta_rt.runtime.signals import ignore_in_child as ignore_stop_signals

_STATE_STYLE = {"idle": "yellow", "armed": "cyan", "balancing": "bold green", "tripped": "bold red",
                "calibrating": "magenta", "swinging_up": "bold cyan", "open_loop": "bold magenta"}


TRACE_S = 10.0  # seconds of θ, φ, u shown as traces
MIN_SPAN = {1: 0.02, 2: 0.02}  # rad: θ and φ traces span at least about a degree (noise is not drawn as motion)
LIMIT_CYCLE_S = 30.0  # seconds of φ the live limit-cycle line looks at
_BARS = "▁▂▃▄▅▆▇█"


@dataclass
class DashboardInfo:
    """What the dashboard knows of the run besides the snapshots (picklable: sent to its process)."""

    title: str = "furuta-rt run"
    log_path: str | None = None
    arm_theta: float = 0.1  # the supervisor's limits (rad), for the hints
    theta_limit: float = 0.5
    phi_limit: float = 6 * math.pi
    live_url: str | None = None  # the Foxglove live view, when served
    u_unit: str = "N m"  # V for a voltage-driven (dc_motor) rig


def _hint_idle(snap: dict[str, Any], info: DashboardInfo) -> str:
    return (f"waiting to arm: bring the pendulum within |θ| < {info.arm_theta:g} rad ({math.degrees(info.arm_theta):.0f}°) "
            f"of upright, θ is {snap['theta']:+.3f} rad now")


def _hint_armed(snap: dict[str, Any], info: DashboardInfo) -> str:
    return f"armed: balancing starts when θ stays within {info.arm_theta:g} rad for a few ticks"


def _hint_balancing(snap: dict[str, Any], info: DashboardInfo) -> str:
    return (f"balancing: trips on |θ| > {info.theta_limit:g} rad, |φ| > {info.phi_limit:.3g} rad, link loss or "
            "overruns; the actuator goes to 0 first")


def _hint_tripped(snap: dict[str, Any], info: DashboardInfo) -> str:
    return f"tripped ({snap.get('trip') or '?'}): the actuator is at 0; the summary follows"


STATE_HINTS: dict[str, Callable[[dict[str, Any], DashboardInfo], str]] = {
    "idle": _hint_idle,
    "armed": _hint_armed,
    "balancing": _hint_balancing,
    "tripped": _hint_tripped,
    "calibrating": lambda snap, info: ("calibrating: the pendulum must hang still for about a second (θ's zero from "
                                       "hanging, the arm's zero); a moving pendulum is refused"),
    "swinging_up": lambda snap, info: ("swinging up: energy control pumps the pendulum to the upright energy; balancing "
                                       "takes over in the catch region (|θ| and energy, rig [swing_up])"),
    "open_loop": lambda snap, info: ("hanging experiment, open loop: the plan's torque drives the arm (no balancing); "
                                     f"trips on |φ| > {info.phi_limit:.3g} rad or the swing limit, link loss or overruns; "
                                     "the actuator goes to 0 first"),
}
"""Per supervisor state: the line saying what it waits for or what ends it."""


def sparkline(values: np.ndarray, width: int, min_span: float = 0.0) -> str:
    """``values`` as a row of ``width`` block characters scaled between their min and max (a range narrower than
    ``min_span`` is drawn as ``min_span`` about its middle: sensor noise is not drawn as full-height swings)."""
    if len(values) == 0:
        return ""
    idx = np.linspace(0, len(values) - 1, min(width, len(values))).round().astype(int)
    v = values[idx]
    lo, hi = float(np.min(v)), float(np.max(v))
    if hi - lo < min_span:
        mid = 0.5 * (lo + hi)
        lo, hi = mid - 0.5 * min_span, mid + 0.5 * min_span
    if hi - lo <= 0:
        return _BARS[0] * len(v)
    levels = np.clip(((v - lo) / (hi - lo) * (len(_BARS) - 1)).round().astype(int), 0, len(_BARS) - 1)
    return "".join(_BARS[k] for k in levels)


class Dashboard:
    """The dashboard's memory of the run (the last ``LIMIT_CYCLE_S`` s of snapshots) and its drawing."""

    def __init__(self, info: DashboardInfo | None = None, trace_width: int = 60) -> None:
        self.info = info or DashboardInfo()
        self.trace_width = trace_width
        self.history: deque[tuple[float, float, float, float]] = deque()  # elapsed, θ, φ, u

    def add(self, snap: dict[str, Any]) -> None:
        h = self.history
        h.append((snap["elapsed"], snap["theta"], snap["phi"], snap["u"]))
        while h and h[0][0] < snap["elapsed"] - LIMIT_CYCLE_S:
            h.popleft()

    def _traces(self) -> Table:
        rows = np.array(self.history, dtype=float).reshape(-1, 4)
        recent = rows[rows[:, 0] >= rows[-1, 0] - TRACE_S] if len(rows) else rows
        grid = Table.grid(padding=(0, 1))
        for _ in range(3):
            grid.add_column()
        for col, name, unit in ((1, "θ", "rad"), (2, "φ", "rad"), (3, "u", self.info.u_unit)):
            v = recent[:, col]
            if col == 1 and len(v) and np.mean(np.cos(v)) < 0:
                # hanging: θ = ±π is one position, so a still pendulum would flip between the trace's ends;
                # drawn as the angle from hanging it is flat when still and swings about the middle
                v, name, unit = np.mod(v, 2 * np.pi) - np.pi, "θ−π", "rad from hanging"
            span = f"{np.min(v):+.3f} … {np.max(v):+.3f} {unit}" if len(v) else ""
            grid.add_row(name, Text(sparkline(v, self.trace_width, MIN_SPAN.get(col, 0.0)), style="cyan"), span)
        return grid

    def _limit_cycle_line(self) -> Text:
        from furuta_rt.stats import limit_cycle_stats

        rows = np.array(self.history, dtype=float).reshape(-1, 4)
        lc = limit_cycle_stats(rows[:, 0], rows[:, 2]) if len(rows) >= 16 else None
        if lc is None:
            seen = rows[-1, 0] - rows[0, 0] if len(rows) else 0.0
            return Text(f"limit cycle: none in φ over the last {seen:.0f} s", style="dim")
        return Text(f"limit cycle: φ ±{lc.amplitude:.3f} rad, period {lc.period:.2f} s ({lc.cycles} cycles)",
                    style="bold yellow")

    def render(self, snap: dict[str, Any] | None) -> Panel:
        """The dashboard for the latest snapshot (None: waiting for the first tick)."""
        info = self.info
        log = f"log: {info.log_path}" if info.log_path else "log: none (--log FILE.mcap to record)"
        footer = [Text(log, style="dim")]
        if info.live_url:
            footer.append(Text(f"live view: {info.live_url} (Foxglove: Open connection → Foxglove WebSocket)", style="dim"))
        footer.append(Text("Ctrl-C to stop", style="bold"))
        if snap is None:
            return Panel(Group(Text("waiting for the device…"), *footer), title=info.title)
        hint = STATE_HINTS.get(snap["state"])
        parts: list[Any] = [render_numbers(snap)]
        if hint is not None:
            parts.append(Text(hint(snap, info), style=_STATE_STYLE.get(snap["state"], "")))
        if self.history:
            parts += [Text(f"last {min(TRACE_S, self.history[-1][0] - self.history[0][0]):.0f} s:", style="dim"),
                      self._traces(), self._limit_cycle_line()]
        return Panel(Group(*parts, *footer), title=info.title)


def render(snap: dict[str, Any] | None, title: str = "furuta-rt run") -> Panel:
    """The dashboard for one snapshot, without history (None: waiting for the first tick)."""
    return Dashboard(DashboardInfo(title=title)).render(snap)


def render_numbers(snap: dict[str, Any]) -> Group:
    """The numbers of one snapshot: state, θ, φ, u, compensation, timing, link, events."""
    grid = Table.grid(padding=(0, 2))
    for _ in range(4):
        grid.add_column()
    state = snap["state"]
    grid.add_row("state", Text(state.upper(), style=_STATE_STYLE.get(state, "")), "time", f"{snap['elapsed']:7.2f} s")
    grid.add_row("θ", f"{math.degrees(snap['theta']):+7.2f}°  ({snap['theta']:+.4f} rad)",
                 "φ", f"{math.degrees(snap['phi']):+7.1f}°  ({snap['phi']:+.3f} rad)")
    grid.add_row("u", f"{snap['u']:+.4f}", "compensation", f"{snap['u_comp']:+.4f}  ({snap['mode']})")
    if snap.get("mode") == "adaptive":
        grid.add_row("", "", "Fc estimate", f"{snap.get('fc_hat', 0.0):.4f} N m")
    grid.add_row("loop rate", f"{snap['rate_hz']:7.1f} Hz", "jitter max", f"{snap['jitter_max_us']:7.0f} µs")
    grid.add_row("overruns", str(snap["overruns"]), "late commands", str(snap["late_commands"]))
    link_ok = snap["seq_gaps"] == 0 and snap["crc_errors"] == 0
    grid.add_row("link", Text("ok" if link_ok else "errors", style="green" if link_ok else "yellow"),
                 "gaps / CRC", f"{snap['seq_gaps']} / {snap['crc_errors']}")
    grid.add_row("ticks", str(snap["ticks"]), "log drops", str(snap["dropped"]))
    parts: list[Any] = [grid]
    if snap.get("trip"):
        parts.append(Text(f"TRIPPED: {snap['trip']}", style="bold red"))
    for message in snap.get("events", []):
        parts.append(Text(message, style="dim"))
    return Group(*parts)


def dashboard_process(q: Any, info: DashboardInfo) -> None:
    """Entry point of the dashboard process (spawned): draw snapshots until None or the parent dies."""
    ignore_stop_signals()  # the daemon handles Ctrl-C (and the rest) and tells us to stop
    parent = multiprocessing.parent_process()
    board = Dashboard(info)
    with Live(board.render(None), auto_refresh=False, transient=False) as live:
        while True:
            try:
                snap = q.get(timeout=0.5)
            except queue.Empty:
                if parent is not None and not parent.is_alive():
                    return
                continue
            except (EOFError, OSError):
                return
            if snap is None:
                return
            board.add(snap)
            live.update(board.render(snap), refresh=True)
