"""The live dashboard: a rich Live view in its own process, fed ≤ 10 snapshots per second.

Rendering a rich table takes milliseconds of Python; in the control process that time would hold
the GIL and make ticks late, so the loop only drops a small dict into a 2-slot queue (``put_nowait``;
a full queue skips the snapshot) and this process draws it.
"""

from __future__ import annotations

import math
import multiprocessing
import queue
import signal
from typing import Any

from rich.console import Group
from rich.live import Live
from rich.panel import Panel
from rich.table import Table
from rich.text import Text

_STATE_STYLE = {"idle": "yellow", "armed": "cyan", "balancing": "bold green", "tripped": "bold red",
                "calibrating": "magenta", "swinging_up": "bold cyan"}


def render(snap: dict[str, Any] | None, title: str = "furuta-rt run") -> Panel:
    """The dashboard for one snapshot (None: waiting for the first tick)."""
    if snap is None:
        return Panel(Text("waiting for the device…"), title=title)
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
    return Panel(Group(*parts), title=title)


def dashboard_process(q: Any, title: str) -> None:
    """Entry point of the dashboard process (spawned): draw snapshots until None or the parent dies."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the daemon handles Ctrl-C and tells us to stop
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    parent = multiprocessing.parent_process()
    with Live(render(None, title), auto_refresh=False, transient=False) as live:
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
            live.update(render(snap, title), refresh=True)
