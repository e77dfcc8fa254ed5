"""The end-of-run summary: what the loop achieved (rate, jitter, latency, faults), how well it balanced,
whether it settled into a limit cycle (thesis sections 5-6: arm friction makes the balanced pendulum
oscillate), and what the mock was told to inject.

To add a figure: a key in ``summary_dict`` and, when it says something, a line from ``_what_happened``
(each line is built by one small function, so others can add theirs without touching the rest).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import asdict
from typing import TYPE_CHECKING, Any

from furuta_rt.runtime.trace import RecentTrace
from furuta_rt.stats import LimitCycle, limit_cycle_stats

if TYPE_CHECKING:
    from furuta_rt.runtime.loop import LoopResult


def limit_cycles(trace: RecentTrace) -> tuple[LimitCycle | None, LimitCycle | None]:
    """The limit cycle of φ and of θ in ``trace`` (furuta_rt.stats, the detector replay uses)."""
    t, theta, phi = trace.arrays()
    if len(t) < 16:
        return None, None
    return limit_cycle_stats(t, phi), limit_cycle_stats(t, theta)


def mock_injections(mock_args: Sequence[str] | None) -> list[str]:
    """The effects and faults a ``--mock`` run asked hil-mock for (its --effect/--fault arguments)."""
    args = list(mock_args or ())
    out = []
    for flag, value in itertools.pairwise(args):
        if flag == "--effect":
            out.append(value)
        elif flag == "--fault":
            out.append(f"fault {value}")
    return out

ENDINGS = {
    "duration": "duration reached",
    "experiment": "experiment plan completed",
    "operator_stop": "stopped by the operator",
    "trip": "TRIPPED",
    "error": "internal error",
}


def _num(x: float) -> float | None:
    return None if x is None or (isinstance(x, float) and not math.isfinite(x)) else float(x)


def summary_dict(r: LoopResult, *, rate_hz: float, mode: str, rig: str, log_path: str | None,
                 warnings: list[str], log_ticks: int | None = None, injected: Sequence[str] = (),
                 comp_source: str = "", fc_hat: float | None = None) -> dict[str, Any]:
    """All figures of the run as one JSON-able dict (``--summary-json``; ``log_ticks``: the ticks the log
    holds, fewer than ``ticks`` when it is incomplete; ``injected``: mock_injections; ``comp_source``: where the
    compensation's parameters came from (--comp-from); ``fc_hat``: the adaptive Coulomb estimate at the end)."""
    def hist(h: Any) -> dict[str, float | None]:
        return {k: _num(v) for k, v in h.summary().items()}

    lc_phi, lc_theta = limit_cycles(r.trace)

    return {
        "rig": rig, "mode": mode, "rate_hz": rate_hz, "end": r.end, "trip_reason": r.trip_reason,
        "trip_message": r.trip_message, "final_state": r.final_state,
        "ticks": r.ticks, "balancing_ticks": r.balancing_ticks, "open_loop_ticks": r.open_loop_ticks,
        "balanced_s": r.balancing_ticks / rate_hz, "device_span_s": r.device_span_s, "host_span_s": r.host_span_s,
        "achieved_rate_hz": _num(r.rate_hz), "device_rate_hz": _num(r.device_rate_hz),
        "period_us": hist(r.period_us), "jitter_us": hist(r.jitter_us), "read_us": hist(r.read_us),
        "update_us": hist(r.update_us), "write_us": hist(r.write_us), "latency_us": hist(r.latency_us),
        "lateness_us": hist(r.lateness_us),
        "overruns": r.overruns, "skipped_periods": r.skipped_periods, "late_commands": r.late_commands,
        "device_overruns": r.device_overruns,
        "device_skipped_periods": r.device_skipped_periods, "seq_gaps": r.seq_gaps, "crc_errors": r.crc_errors,
        "dropped_log_messages": r.dropped_log_messages, "device_link": dict(r.device_link),
        "control_cpu_us_per_tick": _cpu_per_tick(r),
        "std_theta": _num(r.theta.std), "std_phi": _num(r.phi.std), "std_u": _num(r.u.std),
        "mean_u_comp": _num(r.u_comp.mean) if r.u_comp.n else None, "std_u_comp": _num(r.u_comp.std),
        "limit_cycle_phi": asdict(lc_phi) if lc_phi else None, "limit_cycle_theta": asdict(lc_theta) if lc_theta else None,
        "mock_injected": list(injected),
        "comp_source": comp_source or None, "fc_hat": fc_hat,
        "swing_up": _swing_up_dict(r, rate_hz),
        "log": log_path, "log_ticks": log_ticks, "warnings": warnings,
        "events": [{"wall_ns": t, "level": lvl, "message": m} for t, lvl, m in r.events],
    }


def _cpu_per_tick(r: LoopResult) -> dict[str, float] | None:
    """CPU time a tick (µs) of the loop's thread and of the whole control process (None before the first tick)."""
    if not r.ticks:
        return None
    return {"loop": r.loop_cpu_s / r.ticks * 1e6, "process": r.process_cpu_s / r.ticks * 1e6}


def _swing_up_dict(r: LoopResult, rate_hz: float) -> dict[str, Any] | None:
    """The swing-up's figures (None for a run without one)."""
    cal = r.calibration
    if cal is None and r.swing_up_ticks == 0:
        return None
    return {"swing_up_s": r.swing_up_ticks / rate_hz, "first_catch_s": _num(r.first_catch_s),
            "first_catch_run_s": _num(r.first_catch_run_s), "catches": r.catches,
            "falls": r.falls, "theta_zero": None if cal is None else cal.theta_zero,
            "phi_zero": None if cal is None else cal.phi_zero}


def _p(h: Any, unit: str = "µs") -> str:
    if h.count == 0:
        return "n/a"
    return f"p50 {h.percentile(0.5):.0f}  p99 {h.percentile(0.99):.0f}  max {h.max:.0f} {unit}"


def friction_advice(mode: str) -> str:
    """What a limit cycle in φ suggests, given the compensation that ran (section 4: arm Coulomb friction)."""
    if mode in ("none", ""):
        return "arm friction? try --comp coulomb"
    return (f"with {mode} compensation active: more arm friction than it cancels? "
            "furuta-rt diagnose a --log of this run")


def _limit_cycle_line(r: LoopResult, mode: str = "none") -> str | None:
    if r.theta.n <= 1:
        return None
    lc_phi, lc_theta = limit_cycles(r.trace)
    if lc_phi is None:
        span = min(r.trace.n, r.trace.capacity)
        return f"  no limit cycle in φ (none of two or more regular cycles in the last {span} balancing ticks)"
    theta = f"; θ ±{lc_theta.amplitude:.4f} rad" if lc_theta is not None else ""
    return (f"  limit cycle: φ ±{lc_phi.amplitude:.3f} rad, period {lc_phi.period:.2f} s "
            f"({lc_phi.cycles} cycles){theta} — {friction_advice(mode)}")


def _injected_line(injected: Sequence[str]) -> str | None:
    return f"  mock injected: {', '.join(injected)}" if injected else None


def format_summary(r: LoopResult, *, rate_hz: float, mode: str, rig: str, log_path: str | None, limits: str = "",
                   log_ticks: int | None = None, log_incomplete: bool = False, injected: Sequence[str] = (),
                   comp_source: str = "", fc_hat: float | None = None) -> str:
    """The human-readable summary printed at the end of every run (``limits``: the safety limits used;
    ``log_incomplete``: the logger failed and the log holds ``log_ticks`` ticks, None: unreadable;
    ``injected``: what the mock was told to simulate, mock_injections)."""
    nominal = 1e6 / rate_hz
    ending = ENDINGS.get(r.end, r.end)
    if r.end == "trip":
        ending += f" ({r.trip_reason}): {r.trip_message}"
    lines = [
        f"furuta-rt run: rig {rig}, compensation {mode}, {rate_hz:g} Hz — {ending}",
        f"  ticks {r.ticks} over {r.device_span_s:.3f} s device time; loop rate {r.rate_hz:.1f} Hz (host), "
        f"{r.device_rate_hz:.1f} Hz (device); balanced {r.balancing_ticks / rate_hz:.2f} s",
        f"  period jitter |T − {nominal:.0f} µs|: {_p(r.jitter_us)}",
        f"  read {_p(r.read_us)};  update {_p(r.update_us)};  write {_p(r.write_us)}",
        f"  latency sample→command: {_p(r.latency_us)};  tick start lateness: {_p(r.lateness_us)}",
        f"  overruns {r.overruns} ({r.skipped_periods} periods skipped); device: late commands {r.late_commands}, "
        f"own overruns {r.device_overruns} ({r.device_skipped_periods} periods skipped); seq gaps {r.seq_gaps}, "
        f"CRC errors {r.crc_errors}, log drops {r.dropped_log_messages}",
    ]
    cpu = _cpu_per_tick(r)
    if cpu is not None:
        lines.append(f"  control CPU a tick: {cpu['loop']:.0f} µs in the loop ({cpu['loop'] * rate_hz * 1e-4:.1f} % of the "
                     f"period), {cpu['process']:.0f} µs with its helper threads")
    if r.device_link:
        d = r.device_link
        lines.append(f"  device's receiver (its last STATUS, this session): CRC errors {d.get('crc_errors', 0)}, "
                     f"frame errors {d.get('frame_errors', 0)}, UART overruns {d.get('uart_overruns', 0)}, "
                     f"UART line errors {d.get('uart_line_errors', 0)}")
    if comp_source:
        lines.append(f"  compensation: {comp_source}")
    if fc_hat is not None:
        lines.append(f"  adaptive Coulomb estimate at the end: Fc {fc_hat:.4f} N m")
    su = _swing_up_dict(r, rate_hz)
    if su is not None:
        first = "never caught" if su["first_catch_s"] is None else (
            f"first caught {su['first_catch_s']:.2f} s after the swing-up began"
            + (f" ({su['first_catch_run_s']:.2f} s into the run: the calibration and arming before it are not counted)"
               if su["first_catch_run_s"] is not None else ""))
        zeros = "" if r.calibration is None else (f"; calibration θ zero {r.calibration.theta_zero:+.4f} rad, "
                                                  f"arm zero {r.calibration.phi_zero:+.4f} rad")
        lines.append(f"  swing-up: {first}, swinging {su['swing_up_s']:.2f} s, {su['catches']} catch(es), "
                     f"{su['falls']} fall(s){zeros}")
    if r.theta.n > 1:
        lines.append(
            f"  balancing (after its first second): std θ {r.theta.std:.5f} rad, std φ {r.phi.std:.5f} rad, "
            f"std u {r.u.std:.4f}, mean u_comp {r.u_comp.mean:+.4f}"
        )
    if r.open_loop_ticks:
        lines.append(f"  hanging experiment: open loop {r.open_loop_ticks / rate_hz:.2f} s")
    elif r.balancing_ticks == 0 and su is None:
        lines.append("  never balanced: the pendulum was not brought within the arming window (|θ| < arm_theta)")
    lines += [line for line in (_limit_cycle_line(r, mode), _injected_line(injected)) if line]
    if limits:
        lines.append(f"  limits: {limits}")
    if not log_path:
        lines.append("  log: none (use --log FILE.mcap)")
    elif log_incomplete:
        held = "nothing readable" if log_ticks is None else f"{log_ticks} of the {r.ticks} ticks"
        lines.append(f"  log: {log_path} INCOMPLETE, holds {held}")
    else:
        lines.append(f"  log: {log_path} ({r.ticks} ticks)")
    return "\n".join(lines)
