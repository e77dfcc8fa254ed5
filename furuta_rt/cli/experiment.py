"""`furuta-rt experiment design REPORT.json -o plan.toml`: the experiment that separates a report's look-alikes.

    furuta-rt diagnose run.mcap --json report.json                 names a look-alike it cannot separate
    furuta-rt experiment design report.json -o plan.toml           searches the excitation that separates them
    furuta-rt run --port /dev/ttyACM0 --experiment plan.toml --log exp.mcap

It prints what the plan does, how long it runs, the expected separation (diagnose's own test statistic on simulated
recordings of the plan) and the worst |φ|, |θ|, |u| predicted under either alternative or neither; a plan beyond the
rig's limits is refused; an existing plan file is replaced only with --force.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from furuta_rt.cli._common import add_config_argument, add_force_argument, rig_from_args
from furuta_rt.errors import UserError
from furuta_rt.inputs import read_bounded, regular_input
from furuta_rt.io.output import claim_outputs, write_text


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("experiment", help="design an experiment that separates a diagnose report's look-alikes")
    verbs = p.add_subparsers(dest="verb", required=True, metavar="VERB")
    d = verbs.add_parser("design", help="search the excitation that best separates the report's unresolved look-alike",
                         description="Simulate candidate excitations (arm sweeps and steps, chirps and dithers on u; "
                         "with --hanging, torque chirps and dithers with the pendulum hanging) under both alternatives "
                         "with the rig's sensor noise, score each by diagnose's own test statistic for the pair on "
                         "those recordings, and write the best one that keeps within the rig's limits.")
    d.add_argument("report", metavar="REPORT.json", help="`furuta-rt diagnose --json` output")
    d.add_argument("-o", "--output", required=True, metavar="PLAN.toml", help="the plan to write (an existing file "
                   "only with --force)")
    add_config_argument(d)
    add_force_argument(d, "plan file")
    d.add_argument("--budget", type=float, default=30.0, metavar="S", help="seconds of excitation (default 30; the "
                   "settling second and the return to 0 come on top)")
    d.add_argument("--pair", metavar="A,B", help="which look-alike, when the report has several (default: the first)")
    d.add_argument("--max-phi", type=float, metavar="RAD", help="|φ| limit (default: the rig's safety.phi_limit)")
    d.add_argument("--max-theta", type=float, metavar="RAD", help="|θ| limit (default: safety.theta_limit)")
    d.add_argument("--max-u", type=float, metavar="U", help="|u| limit (default: actuator.limit; reaching it is "
                   "saturation)")
    d.add_argument("--hanging", action="store_true", help="design an open-loop plan with the pendulum hanging (torque "
                   "chirps and dithers near its natural frequency: the pendulum's reaction on the arm, which tells an "
                   "input gain from an arm inertia, is far larger than while balancing); --max-theta is then |θ − π| "
                   "(default 1 rad); `run --experiment` runs it open loop from the pendulum hanging at rest")
    d.set_defaults(func=run_design)


MAX_REPORT_BYTES = 64 * 1024 * 1024
"""A diagnose report is kilobytes; more is not one."""


def _load_report(path: str) -> dict:
    if not Path(path).exists() and not Path(path).is_symlink():
        raise UserError(f"{path}: no such report (write one with `furuta-rt diagnose LOG --json {path}`)")
    regular_input(path, "report")  # a FIFO, a device, a link loop: one line, not a hang
    try:
        data = json.loads(read_bounded(path, MAX_REPORT_BYTES, "report").decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError) as err:
        raise UserError(f"{path}: not a diagnose JSON report ({type(err).__name__})") from None
    if not isinstance(data, dict) or not isinstance(data.get("effects"), list):
        raise UserError(f"{path}: not a diagnose JSON report (no 'effects' list)")
    return data


def run_design(args: argparse.Namespace) -> int:
    from furuta_rt.experiment.design import alternatives_from_report, design

    for flag, value in (("--budget", args.budget), ("--max-phi", args.max_phi), ("--max-theta", args.max_theta),
                        ("--max-u", args.max_u)):
        if value is not None and not (math.isfinite(value) and value > 0):
            raise UserError(f"{flag} {value:g}: must be a positive number")
    if Path(args.output).suffix.lower() != ".toml":
        raise UserError(f"-o {args.output}: a plan is a TOML file; give a name ending in .toml")
    claim_outputs([("-o", args.output)], force=args.force, inputs=[args.report])
    rig = rig_from_args(args)
    alt = alternatives_from_report(_load_report(args.report), args.pair)
    from furuta_rt.experiment.hanging import SWING_LIMIT

    mode = "hanging" if args.hanging else "balancing"
    limits = (args.max_phi or rig.safety.phi_limit, args.max_theta or (SWING_LIMIT if args.hanging else rig.safety.theta_limit),
              args.max_u or rig.actuator.limit)
    passive = "" if alt.passive_t is None else f" (paired t {alt.passive_t:.1f} on the recording)"
    print(f"look-alike: {alt.named} ↔ {alt.rival}{passive}", flush=True)

    def progress(i: int, n: int, plan: object, sep: float) -> None:
        print(f"  candidate {i}/{n}: {plan.segments[0].describe()}: expected t {sep:.1f}",  # type: ignore[attr-defined]
              file=sys.stderr, flush=True)

    best, _ = design(rig, alt, args.budget, limits=limits, progress=progress, mode=mode)
    plan = best.plan
    note = f"separates {alt.named} from {alt.rival}: expected {best.test} {best.separation:.1f}"
    plan = type(plan)(plan.segments, plan.mode, plan.settle_s, plan.return_speed, note)
    write_text(args.output, plan.to_toml(), overwrite=args.force, flag="-o")
    total = plan.settle_s + plan.duration
    how = "hanging, open loop" if args.hanging else "while balancing"
    print(f"plan {args.output}: {total:.1f} s {how} (settle {plan.settle_s:g} s, then):")
    for line in plan.describe():
        print(f"  {line}")
    print(f"expected separation: {best.test} {best.separation:.1f} ({alt.named} true: {best.separation_ab[0]:.1f}, "
          f"{alt.rival} true: {best.separation_ab[1]:.1f}; diagnose's own test on simulated recordings of the plan, "
          f"≥ {best.threshold:g} tells them apart)")
    print(f"worst under either or neither: |φ| {best.peak_phi:.3f} rad (limit {limits[0]:g}), "
          f"{'|θ − π|' if args.hanging else '|θ|'} {best.peak_theta:.4f} rad "
          f"(limit {limits[1]:g}), |u| {best.peak_u:.3f} (limit {limits[2]:g})")
    if best.separation < best.threshold:
        need = args.budget * (best.threshold / max(best.separation, 1e-3)) ** 2
        print(f"warning: expected {best.test} {best.separation:.1f} is below {best.threshold:g}: this plan is not "
              f"expected to tell them "
              f"apart; a budget of about {need:.0f} s (t grows as the square root of the length) or looser limits")
    hang = " with the pendulum hanging at rest (open loop)" if args.hanging else ""
    print(f"next: furuta-rt run --port DEV --experiment {args.output} --log experiment.mcap{hang}, then "
          "furuta-rt diagnose RUN.mcap experiment.mcap (the joint fit of both)")
    return 0
