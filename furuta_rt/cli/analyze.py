"""`furuta-rt analyze limit-cycle`: the describing-function analysis of thesis section 4 for any linear
feedback, optionally beside the periodic orbit of the nonlinear loop and a long simulation."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

from furuta_rt.cli._common import add_config_argument, add_force_argument, parse_gains, rig_from_args
from furuta_rt.errors import UserError
from furuta_rt.io.output import claim_outputs, replace_when_done


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("analyze", help="closed-loop analyses (friction limit cycles)")
    analyses = p.add_subparsers(dest="analysis", required=True, metavar="ANALYSIS")
    lc = analyses.add_parser(
        "limit-cycle",
        help="describing-function analysis of the Coulomb-friction limit cycle (thesis section 4)",
        description="G(s) from the arm friction torque to φ̇ for u = L·x, its crossings of the negative real axis, "
        "the predicted limit-cycle frequency and φ̇ amplitude for Coulomb friction Fc (describing function 4Fc/(πC)); "
        "with --orbit also the periodic orbit of the nonlinear loop and a long simulation of it.",
    )
    add_config_argument(lc)
    lc.add_argument("--gains", metavar="L1,L2,L3,L4", help="u = l1 θ + l2 θ̇ + l3 φ + l4 φ̇ (default: the rig's design)")
    lc.add_argument("--fc", metavar="N_m", type=float, default=None,
                    help="Coulomb friction level on the arm, N m (default: the rig's effects.arm_coulomb, else its "
                    "compensation.coulomb.Fc, else 1 as in the thesis)")
    lc.add_argument("--orbit", action="store_true",
                    help="also compute the periodic orbit of the nonlinear loop by shooting and compare with a long simulation")
    lc.add_argument("--loop", choices=("ideal", "sampled", "both"), default="ideal",
                    help="loop for --orbit: ideal (u = L·x of the exact state, continuous), sampled (the rig's loop: "
                    "Bessel path, observer, delay, saturation; no noise) or both (default: ideal)")
    lc.add_argument("--plot", metavar="FILE.png", help="write the Nyquist plot with the describing-function locus")
    lc.add_argument("--json", action="store_true", help="print one JSON object")
    add_force_argument(lc, "--plot file")
    lc.set_defaults(func=run_limit_cycle)


def run_limit_cycle(args: argparse.Namespace) -> int:
    from furuta_rt.analysis.limit_cycle import describing_function_report, limit_cycle_report

    if args.plot and Path(args.plot).suffix.lower() != ".png":
        raise UserError(f"--plot {args.plot}: give a .png file name")
    claim_outputs([("--plot", args.plot)], force=args.force)
    rig = rig_from_args(args)
    gains = parse_gains(args.gains)
    if args.fc is not None and not (math.isfinite(args.fc) and args.fc > 0):
        raise UserError(f"--fc {args.fc}: the Coulomb level must be a positive torque in N m (e.g. --fc 0.3)")
    loops: tuple[str, ...] = ()
    if args.orbit:
        loops = ("ideal", "sampled") if args.loop == "both" else (args.loop,)
    from furuta_rt.replay.progress import steps_bar

    with steps_bar("analyze limit-cycle", 2 * len(loops), enabled=None if loops else False) as step:
        out = limit_cycle_report(rig, gains, args.fc, loops, step=step)
    if args.plot:
        from furuta_rt.analysis.figures import nyquist_figure

        path = Path(args.plot)
        lc, _ = describing_function_report(rig, np.asarray(out["gains"]), out["fc"])
        with replace_when_done(path, overwrite=args.force, flag="--plot") as tmp:
            nyquist_figure([(f"{out['rig']} rig, u = {_law(out['gains'])}\nCoulomb Fc = {out['fc']:g} N m", lc)], tmp)
        out["plot"] = str(path)
    if args.json:
        print(json.dumps(out))
        return 0
    _print(out)
    return 0


def _law(L: list[float]) -> str:
    names = ("θ", "θ̇", "φ", "φ̇")
    terms = [f"{v:.4g}{n}" for v, n in zip(L, names, strict=True) if v != 0.0]
    return " + ".join(terms).replace("+ -", "− ") or "0"


def _print(out: dict) -> None:
    con = Console()
    con.print(f"[bold]rig[/] {out['rig']}   u = {_law(out['gains'])} + F   Coulomb Fc = {out['fc']:g} N m ({out['fc_source']})")
    num = " ".join(f"{v:+.4g}" for v in out["G_num"])
    den = " ".join(f"{v:+.4g}" for v in out["G_den"])
    con.print(f"G(s) = φ̇/F: num [{num}]  den [{den}]  (highest power first)")
    for c in out["crossings"]:
        side = "negative" if c["re"] < 0 else "positive"
        con.print(f"  real-axis crossing at ω = {c['omega_rad_s']:.4g} rad/s, Re G = {c['re']:.4g} ({side})")
    if out["limit_cycle"]:
        con.print(f"[bold yellow]limit cycle predicted[/]: ω = {out['frequency_rad_s']:.4g} rad/s "
                  f"(T = {out['period_s']:.3g} s), φ̇ amplitude {out['amplitude_phidot']:.4g} rad/s, "
                  f"φ {out['amplitude_phi']:.4g} rad, θ {out['amplitude_theta']:.4g} rad"
                  f" — {'stable' if out['limit_cycle_stable'] else 'UNSTABLE'} (Loeb)")
    else:
        con.print("[bold green]no limit cycle predicted[/] (G does not cross the negative real axis at ω > 0)")
    stab = "stable" if out["closed_loop_stable"] else (
        "stable except the unregulated arm (poles at 0)" if out["stable_except_arm_drift"] else "[red]UNSTABLE[/]")
    con.print(f"frictionless closed loop (ideal, A + B L): {stab};  sampled loop with filter/observer: "
              f"{'stable' if out['sampled_loop_stable'] else 'unstable'}")
    if "thesis_case" in out:
        tc = out["thesis_case"]
        con.print(f"thesis {tc['name']}: thesis says {'limit cycle' if tc['thesis_says_limit_cycle'] else 'no limit cycle'}")
    for note in out["notes"]:
        con.print(f"[yellow]note:[/] {note}")
    for loop, rep in out.get("periodic_orbit", {}).items():
        if "error" in rep:
            con.print(f"[red]{loop} loop: no periodic orbit[/]: {rep['error']}")
            continue
        t = Table(title=f"{loop} loop, Coulomb Fc = {rep['fc']:g}: describing function vs periodic orbit vs simulation")
        for col in ("", "period (s)", "φ̇ amp (rad/s)", "φ amp (rad)", "θ amp (rad)", "std θ", "std φ"):
            t.add_column(col, justify="right")
        o, s = rep["orbit"], rep["simulation"]
        if "describing_function" in rep:
            df = rep["describing_function"]
            t.add_row(f"describing function ({loop})", f"{df['period_s']:.4g}", f"{df['amplitude_phidot']:.4g}",
                      f"{df['amplitude_phi']:.4g}", f"{df['amplitude_theta']:.4g}",
                      f"{df['amplitude_theta'] / math.sqrt(2):.4g}", f"{df['amplitude_phi'] / math.sqrt(2):.4g}")
        for name, r in (("periodic orbit", o), ("long simulation", s)):
            a, sd = r["amplitude"], r["std"]
            t.add_row(name, f"{r['period_s']:.4g}", f"{a['phi_dot']:.4g}", f"{a['phi']:.4g}", f"{a['theta']:.4g}",
                      f"{sd['theta']:.4g}", f"{sd['phi']:.4g}")
        con.print(t)
        err = rep["orbit_vs_simulation"]
        con.print(f"orbit vs simulation: period {100 * err['period']:+.3f}%, "
                  f"φ̇ amplitude {100 * err['amplitude_phi_dot']:+.3f}%; orbit residual {o['residual']:.1e}, "
                  f"{'stable' if o['stable'] else 'unstable'}, stuck {100 * o['stuck_fraction']:.0f}% of the period")
        if "describing_function_vs_orbit" in rep:
            d = rep["describing_function_vs_orbit"]
            con.print(f"describing function ({rep['describing_function']['loop']} loop) vs orbit: "
                      f"period {100 * d['period']:+.1f}%, φ̇ amplitude {100 * d['amplitude_phi_dot']:+.1f}%, "
                      f"φ amplitude {100 * d['amplitude_phi']:+.1f}%, θ amplitude {100 * d['amplitude_theta']:+.1f}%")
        if abs(o["drift_phi_dot"]) > 1e-6:
            con.print(f"the orbit drifts: mean arm velocity {o['drift_phi_dot']:.4g} rad/s (φ amplitude about the drift)")
        if "simulation_note" in rep:
            con.print(f"[yellow]note:[/] {rep['simulation_note']}")
        if "describing_function_note" in rep:
            con.print(f"[yellow]note:[/] {rep['describing_function_note']}")
        if "note" in rep:
            con.print(f"[yellow]note:[/] {rep['note']}")
    if "plot" in out:
        con.print(f"Nyquist plot: {out['plot']}")
