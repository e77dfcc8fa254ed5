"""`furuta-rt replay`: re-run the observer and controller offline over a log's recorded samples."""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
from rich.console import Console
from rich.table import Table

from furuta_rt.cli._common import add_force_argument, parse_gains
from furuta_rt.config import COMP_MODES, load_rig
from furuta_rt.io.csv import write_csv
from furuta_rt.io.mcap_read import log_to_recording, read_log, require_ticks
from furuta_rt.io.output import claim_outputs, replace_when_done
from furuta_rt.recording import Recording
from furuta_rt.replay import ReplayResult, replay_log
from furuta_rt.replay.plot import plot_recording
from furuta_rt.replay.progress import progress_bar
from furuta_rt.stats import summary_stats

MODES = COMP_MODES


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "replay",
        help="re-run the controller over a log's samples (determinism check, or another compensation/gains)",
        description="Re-run the observer and controller offline over LOG's recorded samples with the same update "
        "code as the loop. With the logged config the replayed u must equal the logged u exactly; with --comp, "
        "--gains or --config it shows what that controller would have commanded on the same data.",
    )
    p.add_argument("log", metavar="LOG.mcap")
    p.add_argument("--comp", choices=MODES, default=None, help="compensation mode (default: the logged one)")
    p.add_argument("--config", metavar="FILE", default=None, help="rig TOML or shipped rig (default: the rig in the log)")
    p.add_argument("--gains", metavar="L1,L2,L3,L4", default=None, help="state feedback gains (default: the logged ones)")
    p.add_argument("--csv", metavar="OUT.csv", default=None, help="write t, θ, θ̇, φ, replayed u and the logged u")
    p.add_argument("--plot", metavar="OUT.png", default=None, help="plot θ, φ, u and the estimated φ̇")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the report")
    add_force_argument(p, "--csv and --plot files")
    p.set_defaults(func=run)


def _recording(rec: Recording, result: ReplayResult) -> Recording:
    extra = {"u_logged": result.u_logged, "u_lin": result.u_lin, "u_comp": result.u_comp, "phi_dot_hat": result.phi_dot_hat}
    return Recording(t=rec.t, theta=rec.theta, phi=rec.phi, u=result.u, theta_dot=rec.theta_dot, extra=extra, meta=rec.meta)


def run(args: argparse.Namespace) -> int:
    out = Console(soft_wrap=True)
    err = Console(stderr=True)
    claim_outputs([("--csv", args.csv), ("--plot", args.plot)], force=args.force, inputs=[args.log])
    t0 = time.perf_counter()
    with progress_bar("reading") as bar:
        log = require_ticks(read_log(args.log, timing=False, progress=bar))
    t_read = time.perf_counter() - t0
    for w in log.warnings:
        err.print(f"[yellow]warning:[/] {w}", highlight=False, soft_wrap=True)
    rig = load_rig(args.config) if args.config else None
    with progress_bar("replaying") as bar:
        result = replay_log(log, rig=rig, mode=args.comp, gains=parse_gains(args.gains), progress=bar)
    rec = log_to_recording(log)
    bal = result.balancing if result.balancing.any() else np.ones(len(rec), dtype=bool)
    first = int(np.argmax(bal))
    stats = summary_stats(rec.slice(first, len(rec)))
    u_rep = result.u[first:]
    stats["u_replayed"] = {"mean": float(np.mean(u_rep)), "std": float(np.std(u_rep))}
    if args.csv:
        with replace_when_done(args.csv, overwrite=args.force, flag="--csv") as tmp:
            write_csv(_recording(rec, result), tmp, extra=True)
    if args.plot:
        the_rig = rig or log.rig
        unit = "V" if the_rig is not None and the_rig.actuator.kind == "dc_motor" else "N m"
        with replace_when_done(args.plot, overwrite=args.force, flag="--plot") as tmp:
            plot_recording(rec, tmp, u_replayed=result.u, phi_dot_replayed=result.phi_dot_hat,
                           title=f"{log.path.name}: replay with mode {result.mode}", u_unit=unit)
    failed = result.same_config and not result.converted and not result.exact
    if args.json:
        print(json.dumps({
            "log": str(log.path), "ticks": log.n_ticks, "duration": log.duration, "recovered": log.recovered,
            "warnings": log.warnings, "mode": result.mode, "gains": list(result.gains), "same_config": result.same_config,
            "converted": result.converted, "exact": result.exact, "mismatches": result.n_mismatch,
            "max_abs_du": result.max_abs_du, "verdict": result.verdict(), "stats": stats,
            "read_s": t_read, "replay_s": result.wall_seconds,
        }))
        return 1 if failed else 0
    rig_name = (rig or log.rig).name if (rig or log.rig) else "?"
    out.print(f"[bold]{log.path}[/]: {log.n_ticks} ticks, {log.duration:.2f} s, rig {rig_name}, "
              f"replayed with mode {result.mode}, L = [{', '.join(f'{g:.4g}' for g in result.gains)}]", highlight=False)
    style = "red" if failed else ("green" if result.same_config and result.exact else "cyan")
    out.print(f"[{style}]{result.verdict()}[/]", highlight=False)
    _print_stats(out, stats)
    speed = log.duration / max(t_read + result.wall_seconds, 1e-9)
    out.print(f"read {t_read:.2f} s + replay {result.wall_seconds:.2f} s = {speed:.0f}× real time", highlight=False)
    for path in (args.csv, args.plot):
        if path:
            out.print(f"wrote {path}", highlight=False)
    return 1 if failed else 0


def _print_stats(out: Console, stats: dict) -> None:
    t = Table(title=f"summary over {stats['duration']:.2f} s (from the first balancing tick)")
    t.add_column("")
    t.add_column("mean", justify="right")
    t.add_column("std", justify="right")
    for name, label in (("theta", "θ (rad)"), ("phi", "φ (rad)"), ("u", "u logged"), ("u_replayed", "u replayed")):
        s = stats.get(name)
        if s:
            t.add_row(label, f"{s['mean']:.4g}", f"{s['std']:.4g}")
    out.print(t)
    for name, label in (("limit_cycle_phi", "φ"), ("limit_cycle_theta", "θ")):
        lc = stats.get(name)
        if lc:
            out.print(f"limit cycle in {label}: amplitude {lc['amplitude']:.4g} rad, period {lc['period']:.3f} s "
                      f"({lc['cycles']} cycles)", highlight=False)
        else:
            out.print(f"no clear limit cycle in {label}", highlight=False)
