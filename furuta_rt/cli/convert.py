"""`furuta-rt convert`: recordings between our CSV, other rigs' CSVs (column mapping) and MCAP logs."""

from __future__ import annotations

import argparse
from pathlib import Path

from rich.console import Console

from furuta_rt.cli._common import add_force_argument
from furuta_rt.config import load_rig
from furuta_rt.errors import UserError
from furuta_rt.io.mapping import SHIPPED_MAPPINGS, load_mapping
from furuta_rt.io.mcap_read import is_mcap
from furuta_rt.io.output import claim_outputs, replace_when_done
from furuta_rt.io.recordings import output_format, read_recording, write_recording
from furuta_rt.replay.plot import plot_recording
from furuta_rt.replay.progress import progress_bar


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "convert",
        help="convert a recording: CSV (t, theta, theta_dot, phi, u) ⇄ MCAP log; other rigs' CSVs with --mapping",
        description="Convert a recording. The output format follows OUTPUT's extension (.mcap or .csv). A CSV from "
        "another rig is read through a column mapping (--mapping; shipped: " + ", ".join(SHIPPED_MAPPINGS) + ").",
    )
    p.add_argument("input", metavar="INPUT", help="a .csv recording or a .mcap log")
    p.add_argument("-o", "--output", metavar="OUTPUT", required=True,
                   help="OUTPUT.mcap or OUTPUT.csv (an existing file only with --force)")
    add_force_argument(p, "OUTPUT and --plot files")
    p.add_argument("--mapping", metavar="NAME|FILE", default=None, help="column mapping for another rig's CSV")
    p.add_argument("--map", metavar="FIELD.KEY=VALUE", action="append", default=[],
                   help="override one mapping key, e.g. u.scale=10 or theta.source=angle (repeatable)")
    p.add_argument("--config", metavar="FILE", default=None,
                   help="rig TOML or shipped rig written into the log (default: the mapping's rig, else thesis)")
    p.add_argument("--extra", action="store_true", help="CSV output: also write the extra columns (φ̂̇, u_lin, …)")
    p.add_argument("--plot", metavar="OUT.png", default=None,
                   help="also plot θ, φ, u, φ̇ of the recording (an existing file only with --force)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    con = Console(soft_wrap=True)
    src, dst = Path(args.input), Path(args.output)
    if src.resolve() == dst.resolve():
        raise UserError(f"output {dst} is the input; give another -o")
    to_log = output_format(dst) == ".mcap"
    if is_mcap(src) and to_log:
        raise UserError(f"{src} is already an MCAP log; to rewrite a log left by a killed run use `furuta-rt repair {src}`")
    claim_outputs([("-o", dst), ("--plot", args.plot)], force=args.force, inputs=[src])
    mapping = None
    if args.mapping or args.map:
        if is_mcap(src):
            raise UserError(f"{src} is an MCAP log; --mapping and --map apply to CSV input only")
        if not args.mapping:
            raise UserError("--map needs --mapping (the mapping it overrides)")
        mapping = load_mapping(args.mapping, args.map)
    rig_name = args.config or (mapping.rig if mapping is not None else None)
    rig = load_rig(rig_name) if rig_name else None
    with progress_bar(f"reading {src.name}") as bar:
        rec = read_recording(src, mapping, rig, progress=bar)
    for w in rec.meta.get("warnings", []):  # type: ignore[union-attr]
        Console(stderr=True, soft_wrap=True).print(f"[yellow]warning:[/] {w}", highlight=False)
    if to_log and rig is None:
        rig = load_rig("thesis")
    with replace_when_done(dst, overwrite=args.force, flag="-o") as tmp, progress_bar(f"writing {dst.name}") as bar:
        write_recording(rec, tmp, rig, extra=args.extra, progress=bar)
    unit = "V" if rig is not None and rig.actuator.kind == "dc_motor" else "N m"
    rig_text = f", rig {rig.name}" if to_log and rig else ""
    con.print(f"wrote {dst}: {len(rec)} rows, {rec.duration:.2f} s{rig_text}", highlight=False)
    for note in rec.meta.get("notes", []):  # type: ignore[union-attr]
        con.print(f"note: {note}", highlight=False)
    if args.plot:
        with replace_when_done(args.plot, overwrite=args.force, flag="--plot") as tmp:
            plot_recording(rec, tmp, title=f"{src.name}", u_unit=unit)
        con.print(f"wrote {args.plot}", highlight=False)
    return 0
