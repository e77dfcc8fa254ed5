"""`furuta-rt diagnose`: find the physics the model left out of a recording, model it, show the fit improve."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from rich.console import Console

from furuta_rt.config import SHIPPED_RIGS, RigConfig, load_rig
from furuta_rt.errors import UserError
from furuta_rt.recording import Recording


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "diagnose",
        help="locate where a recording departs from the model, name and fit the missing physics",
        description="Compare RECORDING (an MCAP log, or a CSV with t, theta, theta_dot, phi, u) with the rig's model "
        "(eq. 4 with the measurement path): locate the mismatch, rank named physical effects on held-out data, fit "
        "them, and show the fit improve. Without --config the rig in the log, else the thesis rig (Bessel θ path at "
        "50 rad/s), is assumed.",
    )
    p.add_argument("recording", metavar="RECORDING")
    p.add_argument("--config", metavar="RIG.toml", default=None,
                   help=f"rig TOML file or a shipped rig ({', '.join(SHIPPED_RIGS)})")
    p.add_argument("--mapping", metavar="NAME|FILE", default=None,
                   help="column mapping for another rig's CSV (e.g. macstepien; see furuta_rt/io/mappings)")
    p.add_argument("--json", metavar="OUT.json", default=None, help="write the diagnosis as one JSON object ('-': stdout)")
    p.add_argument("--report", metavar="OUT_DIR", default=None, help="write figures and summary.md into this directory")
    p.add_argument("--theta-filter", metavar="none|RAD_S", default=None,
                   help="the θ channel's Bessel cutoff instead of the config's; 'none' for an encoder on the pendulum")
    p.add_argument("--no-closed-loop", action="store_true", help="skip the closed-loop re-simulation (faster)")
    p.set_defaults(func=run)


def load(path: str, config: str | None, mapping: str | None) -> tuple[Recording, RigConfig]:
    """The recording and the rig to diagnose it against (--config, else the log's rig, else thesis)."""
    from furuta_rt.io.mcap_read import is_mcap, log_to_recording, read_log
    from furuta_rt.io.recordings import read_recording

    p = Path(path)
    if not p.exists():
        raise UserError(f"recording {p} does not exist")
    if p.is_dir():
        raise UserError(f"recording {p} is a directory; give an MCAP log or a CSV file")
    rig = load_rig(config) if config else None
    if is_mcap(p):
        log = read_log(p, timing=False)
        rec = log_to_recording(log)
        if rig is None:
            rig = log.rig or load_rig("thesis")
        if log.mode:
            rec.meta["mode"] = log.mode
        return rec, rig
    if rig is None and mapping:
        from furuta_rt.io.mapping import load_mapping

        m = load_mapping(mapping)
        rig = load_rig(m.rig) if m.rig else None
    rec = read_recording(p, mapping=mapping, rig=rig)
    return rec, rig or load_rig("thesis")


def with_theta_filter(rig: RigConfig, text: str) -> RigConfig:
    """The rig with another θ measurement path: 'none' (θ measured directly) or a Bessel cutoff in rad/s."""
    if text.strip().lower() == "none":
        cutoff = None
    else:
        try:
            cutoff = float(text)
        except ValueError:
            raise UserError(f"--theta-filter {text!r}: give 'none' or a cutoff in rad/s (e.g. 50)") from None
        if not cutoff > 0:
            raise UserError(f"--theta-filter {text!r}: the cutoff must be > 0 rad/s")
    return rig.model_copy(update={"sensors": rig.sensors.model_copy(update={"bessel_cutoff": cutoff})})


def run(args: argparse.Namespace) -> int:
    from furuta_rt.diagnose import Options, diagnose
    from furuta_rt.diagnose.report import text, write_report

    rec, rig = load(args.recording, args.config, args.mapping)
    if args.theta_filter is not None:
        rig = with_theta_filter(rig, args.theta_filter)
    d = diagnose(rec, rig, Options(closed_loop=not args.no_closed_loop))
    out = d.to_json()
    if args.json == "-":
        print(json.dumps(out, default=float))
    else:
        con = Console(soft_wrap=True, highlight=False)
        for line in text(d):
            con.print(line, markup=False)
        if args.json:
            try:
                Path(args.json).write_text(json.dumps(out, indent=1, default=float) + "\n")
            except OSError as err:
                raise UserError(f"cannot write {args.json}: {err.strerror}") from None
    if args.report:
        try:
            paths = write_report(d, Path(args.report))
        except OSError as err:
            raise UserError(f"cannot write the report into {args.report}: {err.strerror}") from None
        if args.json != "-":
            Console().print(f"report: {paths[-2]}", markup=False)
    return 0
