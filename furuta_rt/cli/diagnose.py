"""`furuta-rt diagnose`: find the physics the model left out of a recording, model it, show the fit improve."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from rich.console import Console

from furuta_rt.cli._common import add_force_argument
from furuta_rt.config import SHIPPED_RIGS, RigConfig, load_rig, require_plausible
from furuta_rt.errors import UserError
from furuta_rt.io.output import claim_directory, claim_outputs, directory_when_done, write_text
from furuta_rt.recording import Recording

if TYPE_CHECKING:
    from furuta_rt.diagnose import Options


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "diagnose",
        help="locate where a recording departs from the model, name and fit the missing physics",
        description="Compare RECORDING (an MCAP log, or a CSV with t, theta, theta_dot, phi, u) with the rig's model "
        "(eq. 4 with the measurement path): locate the mismatch, rank named physical effects on held-out data, fit "
        "them, and show the fit improve. Without --config the rig in the log, else the thesis rig (Bessel θ path at "
        "50 rad/s), is assumed.",
    )
    p.add_argument("recording", metavar="RECORDING", nargs="+",
                   help="a recording; several recordings of one rig (e.g. a run and its designed experiment, "
                   "`furuta-rt experiment design`) are fitted jointly: shared physical parameters, and whether the "
                   "look-alikes a recording alone left unresolved are told apart together")
    p.add_argument("--config", metavar="RIG.toml", default=None,
                   help=f"rig TOML file or a shipped rig ({', '.join(SHIPPED_RIGS)})")
    p.add_argument("--mapping", metavar="NAME|FILE", default=None,
                   help="column mapping for another rig's CSV (e.g. macstepien; see furuta_rt/io/mappings)")
    p.add_argument("--map", metavar="FIELD.KEY=VALUE", action="append", default=[],
                   help="override a mapping key (e.g. phi.scale=-1, theta.scale=0.0174533); without --mapping, the scale "
                   "and offset of a plain CSV's columns (θ's scale applies to theta_dot too)")
    p.add_argument("--skip-convention-check", action="store_true",
                   help="diagnose even when the signs or angle units look unlike the rig's (see docs/DIAGNOSE.md)")
    p.add_argument("--json", metavar="OUT.json", default=None, help="write the diagnosis as one JSON object ('-': stdout)")
    p.add_argument("--report", metavar="OUT_DIR", default=None,
                   help="write report.html (figures, summary.md, diagnosis.json beside it) into this directory")
    p.add_argument("--theta-filter", metavar="none|RAD_S", default=None,
                   help="the θ channel's Bessel cutoff instead of the config's; 'none' for an encoder on the pendulum")
    p.add_argument("--no-closed-loop", action="store_true", help="skip the closed-loop re-simulation (faster)")
    p.add_argument("--also-search", metavar="EFFECT", action="append", default=[],
                   help="try a registered effect that is outside the default search too (e.g. arm_air_drag); repeatable")
    add_force_argument(p, "--json file and the earlier report in --report's directory")
    p.set_defaults(func=run)


def load(path: str, config: str | None, mapping: str | None, overrides: list[str] | None = None) -> tuple[Recording, RigConfig]:
    """The recording and the rig to diagnose it against (--config, else the log's rig, else thesis); ``overrides``:
    --map FIELD.KEY=VALUE (a mapping's keys, or the scale/offset of a plain CSV's columns)."""
    from furuta_rt.io.mcap_read import is_mcap, log_to_recording, read_log
    from furuta_rt.io.recordings import read_recording

    p = Path(path)
    if not p.exists():
        raise UserError(f"recording {p} does not exist")
    if p.is_dir():
        raise UserError(f"recording {p} is a directory; give an MCAP log or a CSV file")
    rig = load_rig(config) if config else None
    if p.suffix.lower() == ".mcap" and not is_mcap(p):
        raise UserError(f"{p} is named .mcap but is not an MCAP file (it does not start with the MCAP magic); "
                        "give a log written by furuta-rt run, or a CSV named .csv")
    if is_mcap(p):
        if overrides:
            raise UserError(f"{p} is an MCAP log; --map applies to CSV input only")
        log = read_log(p, timing=False)
        if len(log.ticks.get("t", ())) == 0:  # nothing recoverable: one line, not the warnings of a torn log
            raise UserError(f"{p} holds no ticks: no complete chunk could be read (0 samples)")
        rec = log_to_recording(log)
        for w in log.warnings:  # a torn or unclosed log: read to its last complete chunk, said here
            _warn(w)
        if rig is None:
            rig = log.rig or load_rig("thesis")
        if log.mode:
            rec.meta["mode"] = log.mode
        return rec, rig
    if mapping:
        from furuta_rt.io.mapping import load_mapping

        m = load_mapping(mapping, overrides or ())
        if rig is None:
            rig = load_rig(m.rig) if m.rig else None
        rec = read_recording(p, mapping=m, rig=rig)
    else:
        from furuta_rt.io.csv import read_csv

        rec = rescaled(read_csv(p, gaps=True), overrides or [])  # gaps and repeated times: repaired by diagnose
    from furuta_rt.diagnose.sanity import time_in_seconds

    rec, note = time_in_seconds(rec)
    if note:
        _warn(note)
        rec.meta["input_notes"] = [*rec.meta.get("input_notes", []), note]
    return rec, rig or load_rig("thesis")


def _warn(line: str) -> None:
    Console(stderr=True, soft_wrap=True).print(f"furuta-rt diagnose: warning: {line}", markup=False)


def rescaled(rec: Recording, overrides: list[str]) -> Recording:
    """A plain CSV's columns with --map FIELD.scale / FIELD.offset applied (value = scale·column + offset)."""
    import dataclasses

    from furuta_rt.io.mapping import _angle

    cols: dict[str, np.ndarray] = {}
    for item in overrides:
        key, sep, value = item.partition("=")
        field, _, what = key.strip().partition(".")
        if not sep or field not in ("theta", "theta_dot", "phi", "u") or what not in ("scale", "offset"):
            raise UserError(f"--map {item!r}: without --mapping, give theta|theta_dot|phi|u.scale|offset=VALUE "
                            "(e.g. phi.scale=-1)")
        try:
            v = _angle(value.strip())
        except ValueError:
            raise UserError(f"--map {item!r}: {value.strip()!r} is not a number") from None
        base = cols.get(field, getattr(rec, field))
        if base is None:
            raise UserError(f"--map {item!r}: the recording has no {field} column")
        cols[field] = base * v if what == "scale" else base + v
        if field == "theta" and what == "scale" and rec.theta_dot is not None and not any(
                o.strip().startswith("theta_dot.") for o in overrides):
            cols["theta_dot"] = cols.get("theta_dot", rec.theta_dot) * v
    return dataclasses.replace(rec, **cols) if cols else rec


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
    if len(args.recording) > 1:
        return run_joint(args)
    args.recording = args.recording[0]
    # every output claimed before the diagnosis: a user's files are never overwritten, and a refusal comes first
    claim_outputs([("--json", None if args.json == "-" else args.json)], force=args.force, inputs=[args.recording])
    if args.report:
        from furuta_rt.diagnose.report.render import OUTPUTS, check_directory

        check_directory(Path(args.report))
        claim_directory("--report", args.report, OUTPUTS, force=args.force)
        if args.json and Path(args.json).name in OUTPUTS and Path(args.json).resolve().parent == Path(args.report).resolve():
            raise UserError(f"--json {args.json} is one of the report's own files; give it another name")
    rec, rig = load(args.recording, args.config, args.mapping, args.map)
    # a value no Furuta pendulum has is a unit mistake (cm as m, degrees as rad), not physics to find: refused as
    # `run` refuses it, one line naming the key and the likely unit
    require_plausible(rig, args.config or f"the rig {rig.name!r} of {args.recording}")
    if args.theta_filter is not None:
        rig = with_theta_filter(rig, args.theta_filter)
    # the diagnosis (scipy, matplotlib: seconds to import) once the input is read: a bad one is refused at once
    from furuta_rt.diagnose.report.render import OUTPUTS, text, write_report
    from furuta_rt.diagnose.segments import SegmentedDiagnosis, diagnose_recording, split_at_gaps

    split = split_at_gaps(rec)  # a recording with gaps is diagnosed as the stretches between them
    if args.report and len(split.segments) > 1:
        raise UserError(f"--report writes the page of one continuous recording; {args.recording} splits into "
                        f"{len(split.segments)} segments at its gaps: use --json")
    opts = _options(args)
    d = diagnose_recording(rec, rig, opts, split)
    if isinstance(d, SegmentedDiagnosis):
        _print_and_write(args, d.to_json(), d.text())
        return 0
    _print_and_write(args, d.to_json(), text(d))
    if args.report:
        try:
            with directory_when_done(args.report, OUTPUTS, overwrite=args.force, flag="--report") as tmp:
                write_report(d, tmp)
        except OSError as err:
            raise UserError(f"cannot write the report into {args.report}: {err.strerror}") from None
        if args.json != "-":
            Console().print(f"report: {Path(args.report) / 'report.html'}", markup=False)
    return 0


def run_joint(args: argparse.Namespace) -> int:
    """Several recordings of one rig fitted jointly (furuta_rt.diagnose.joint)."""
    from furuta_rt.diagnose.jointly import diagnose_joint, text

    if args.report:
        raise UserError("--report writes the page of one recording; with several, use --json (or diagnose each alone)")
    if len(set(map(str, map(Path, args.recording)))) < len(args.recording):
        raise UserError("a recording is given twice; a joint fit needs distinct recordings")
    claim_outputs([("--json", None if args.json == "-" else args.json)], force=args.force, inputs=args.recording)
    loaded = [load(path, args.config, args.mapping, args.map) for path in args.recording]
    rig = loaded[0][1]
    if args.config is None:  # each log carries its rig: one rig is what a joint fit means
        for path, (_, other) in zip(args.recording[1:], loaded[1:], strict=True):
            if other.model_dump() != rig.model_dump():
                raise UserError(f"{path} was recorded on another rig than {args.recording[0]} ({other.name} against "
                                f"{rig.name}); give --config to diagnose both against one rig")
    if args.theta_filter is not None:
        rig = with_theta_filter(rig, args.theta_filter)
    opts = _options(args)
    j = diagnose_joint([(path, rec) for path, (rec, _) in zip(args.recording, loaded, strict=True)], rig, opts)
    _print_and_write(args, j.to_json(), text(j))
    return 0


def _print_and_write(args: argparse.Namespace, out: dict, lines: list[str]) -> None:
    """The JSON on stdout (--json -), else the text, and the JSON into --json's file."""
    if args.json == "-":
        print(json.dumps(out, default=float))
        return
    con = Console(soft_wrap=True, highlight=False)
    for line in lines:
        con.print(line, markup=False)
    if args.json:
        try:
            write_text(args.json, json.dumps(out, indent=1, default=float) + "\n", overwrite=args.force, flag="--json")
        except OSError as err:
            raise UserError(f"cannot write {args.json}: {err.strerror}") from None


def _options(args: argparse.Namespace) -> Options:
    """diagnose's Options from the command line; an --also-search name that is no effect outside the default search is
    refused in one line."""
    from furuta_rt.diagnose import Options
    from furuta_rt.model.effects import EFFECT_TYPES

    optional = sorted(name for name, cls in EFFECT_TYPES.items() if not cls.searched)
    for name in args.also_search:
        if name not in optional:
            why = "is searched already" if name in EFFECT_TYPES else "is not a registered effect"
            raise UserError(f"--also-search {name}: {why}; the effects outside the default search are "
                            f"{', '.join(optional) or 'none'}")
    return Options(closed_loop=not args.no_closed_loop, check_conventions=not args.skip_convention_check,
                   also_search=tuple(args.also_search))
