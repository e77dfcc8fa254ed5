"""`furuta-rt design`: gains, closed-loop poles (with the filter and observer) and margins."""

from __future__ import annotations

import argparse
import json

import numpy as np
from rich.console import Console
from rich.table import Table

from furuta_rt.cli._common import add_config_argument, parse_gains, rig_from_args
from furuta_rt.controller.design import place_gains
from furuta_rt.controller.loop_analysis import analyze, minimum_stable_cutoff
from furuta_rt.model.plant import FurutaPlant


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "design", help="print the gains, closed-loop poles and stability margins",
        description="The state-feedback gains of the rig's design (eq. 7 pole placement, or LQR, or --gains), the "
        "closed-loop poles of the sampled loop with the θ filter, the observer and the command delay, and the gain and "
        "phase margins. Exit 0 when the closed loop is stable, 1 when it is not, 2 on bad input.")
    add_config_argument(p)
    p.add_argument("--gains", metavar="L1,L2,L3,L4", help="analyse these gains instead of the configured design")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run)


def design_report(args: argparse.Namespace) -> dict:
    rig = rig_from_args(args)
    gains = parse_gains(args.gains)
    report = analyze(rig, None if gains is None else np.asarray(gains))
    plant = FurutaPlant(rig.lumped())
    A, B = plant.linearize()
    p = rig.lumped()
    out: dict = {
        "rig": rig.name,
        "design": "gains" if gains is not None else rig.control.design,
        "L": [float(v) for v in report.gains],
        "poles": [[float(s.real), float(s.imag)] for s in report.poles_s],
        "poles_z": [[float(z.real), float(z.imag)] for z in report.poles_z],
        "ideal_poles": [[float(s.real), float(s.imag)] for s in sorted(report.ideal_poles, key=lambda s: s.real)],
        "stable": report.stable,
        "gain_margin": [report.gain_margin_down, report.gain_margin_up],
        "phase_margin_deg": report.phase_margin_deg,
        "lumped": {"alpha": p.alpha, "beta": p.beta, "gamma": p.gamma, "epsilon": p.epsilon},
        "A": A.tolist(),
        "B": B.ravel().tolist(),
        "rate_hz": rig.control.rate_hz,
        "bessel_cutoff": rig.sensors.bessel_cutoff,
        "notes": list(report.notes),
    }
    if gains is None and rig.control.design == "pole_placement":
        place = place_gains(plant, report.ideal_poles)
        out["L_place"] = [float(v) for v in place]
    if not report.stable and rig.sensors.bessel_cutoff:
        needed = minimum_stable_cutoff(rig)
        out["minimum_stable_cutoff"] = needed
        if needed is not None:
            out["notes"].append(f"the loop needs a Bessel cutoff above {needed:.1f} rad/s")
    return out


def pole_rows(poles: list[list[float]], rate_hz: float) -> list[tuple[float, str, str]]:
    """The poles as table rows, slowest first, each complex pair as one row ``±im``. A sampled pole on the negative
    real axis (z < 0) has no continuous equivalent of its own: it is shown at the Nyquist frequency, ±π·rate."""
    nyquist = np.pi * rate_hz
    rows: dict[tuple[float, float], tuple[float, str, str]] = {}
    for re, im in poles:
        key = (round(re, 6), round(abs(im), 6))
        if abs(abs(im) - nyquist) < 1e-6 * nyquist:
            rows[key] = (re, f"±{nyquist:.3f}", "z < 0: oscillates every tick")
        elif abs(im) > 1e-9:
            rows[key] = (re, f"±{abs(im):.3f}", "")
        else:
            rows[key] = (re, "0", "")
    return sorted(rows.values(), key=lambda r: -r[0])


def run(args: argparse.Namespace) -> int:
    out = design_report(args)
    if args.json:
        print(json.dumps(out))
        return 0 if out["stable"] else 1
    con = Console()
    con.print(f"[bold]rig[/] {out['rig']}   design {out['design']}   loop {out['rate_hz']:g} Hz   "
              f"θ filter: Bessel {out['bessel_cutoff']} rad/s")
    lp = out["lumped"]
    con.print(f"α = {lp['alpha']:.6g}  β = {lp['beta']:.6g}  γ = {lp['gamma']:.6g}  ε = {lp['epsilon']:.6g}")
    con.print("u = L·x,  L = [" + ", ".join(f"{v:.4f}" for v in out["L"]) + "]")
    if "L_place" in out:
        con.print("cross-check python-control place: [" + ", ".join(f"{v:.4f}" for v in out["L_place"]) + "]")
    con.print("[bold]closed-loop poles[/] (plant + filter + observer + command delay, continuous equivalent):")
    t = Table()
    t.add_column("re (1/s)", justify="right")
    t.add_column("im (rad/s)", justify="right")
    for re, im, note in pole_rows(out["poles"], out["rate_hz"]):
        t.add_row(f"{re:.3f}", im, note)
    con.print(t)
    con.print("designed poles (no filter/observer/delay): " + ", ".join(f"{re:.2f}{im:+.2f}j" for re, im in out["ideal_poles"]))
    gm = out["gain_margin"]
    if out["stable"]:
        con.print(f"gain margin: stable for loop gain × [{gm[0]:.3f}, {gm[1]:.3f}]   "
                  f"phase margin: {out['phase_margin_deg']:.1f}°")
    else:
        con.print("gain and phase margins: none (the loop is unstable at its own gain)")
    con.print("[green]closed loop stable[/]" if out["stable"] else "[bold red]closed loop UNSTABLE[/]")
    for note in out["notes"]:
        con.print(f"[yellow]note:[/] {note}")
    return 0 if out["stable"] else 1
