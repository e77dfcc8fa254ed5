"""`furuta-rt run`: the fixed-rate control daemon (balancing, safety supervisor, MCAP log, live dashboard).

    furuta-rt run --mock --duration 10                 balance the simulated pendulum (no hardware)
    furuta-rt run --port /dev/ttyACM0 --log run.mcap   the rig
    furuta-rt run --mock --swing-up                    calibrate hanging, swing up, catch and balance
    furuta-rt run --mock --experiment plan.toml        balance and run a designed experiment (ends with the plan)
                                                       (a hanging plan: open loop, the pendulum hanging)

Exit codes: 0 duration reached or operator stop (SIGINT, SIGQUIT, SIGTERM, SIGHUP: u = 0 and STOP sent
first, log closed, summary printed); 1 the safety supervisor tripped (reason printed); 2 user error (one
line, no traceback); 3 the run ended but its log is incomplete (disk full, ...); 4 the run ended without
ever balancing (not after an operator stop); 128 + the signal's number (129 SIGHUP, 130 SIGINT, 131
SIGQUIT, 143 SIGTERM) interrupted during start-up. A later output that fails does not change the code.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any

from furuta_rt.cli._common import add_config_argument, add_force_argument, parse_gains, rig_from_args
from furuta_rt.config import COMP_MODES, RigConfig
from furuta_rt.cpu_placement import check_cpu_option
from furuta_rt.errors import UserError
from furuta_rt.io.output import claim_outputs

MOCK_TIMEOUT_MS = 500.0
"""With --mock the timing trips (link loss, device watchdog, repeated overruns) tolerate stalls up to
this long: hil-mock is a Python process, and a pseudo-terminal hands bytes over in kernel workers that
are not real-time; on a loaded 2-core machine both stall now and then for 100-200 ms (measured), where a
rig's MCU and USB link do not. The pendulum survives such stalls; they are measured and logged all the
same. A rig (--port) gets the strict limits of its [safety] table."""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "run",
        help="run the balancing loop on the rig (--port) or the simulated pendulum (--mock)",
        description="Fixed-rate control daemon: read SAMPLE → u = L·x + friction compensation → COMMAND, "
        "with a safety supervisor, an MCAP log and a live dashboard. Exit 0: duration reached or stopped "
        "by the operator (Ctrl-C) after balancing; 1: tripped; 2: user error; 3: the log is incomplete (disk full); "
        "4: never balanced.",
    )
    add_config_argument(p)
    src = p.add_mutually_exclusive_group()
    src.add_argument("--port", metavar="DEV", help="serial device of the DAQ, e.g. /dev/ttyACM0")
    src.add_argument("--mock", action="store_true", help="start hil-mock (the simulated pendulum) on a pty and use it")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds of device time (default: until Ctrl-C)")
    p.add_argument("--log", metavar="FILE.mcap", help="write every tick to this MCAP file (opens in Foxglove); "
                   "an existing file only with --force")
    add_force_argument(p, "--log and --summary-json files", "the log once the device has answered, not before")
    p.add_argument("--swing-up", action="store_true", help="start from the pendulum hanging at rest: calibrate θ's zero "
                   "(~1 s still), swing up by energy control, catch and balance; a fall swings up again (the rig's "
                   "swing_up.on_fall); with --mock the mock starts hanging")
    p.add_argument("--experiment", metavar="PLAN.toml", help="run a designed experiment (`furuta-rt experiment design` "
                   "writes one): while balancing (arm-reference steps, ramps, sweeps; chirps and dithers added to u) "
                   "or, for a hanging plan, open loop with the pendulum hanging (its chirps and dithers are the whole "
                   "command; trips beyond |θ − π| = 1 rad; with --mock the mock starts hanging); its segments are "
                   "logged as events, the run ends when the plan does")
    p.add_argument("--comp", choices=COMP_MODES, help="friction compensation (default: the config's compensation.mode); "
                   "adaptive: Coulomb compensation whose level is estimated online while balancing")
    p.add_argument("--comp-from", metavar="REPORT.json", help="compensate the arm friction that `furuta-rt diagnose "
                   "--json` found (Coulomb, stiction, LuGre, viscous): its parameters, the mode chosen from them")
    p.add_argument("--rate", type=int, metavar="HZ", help="loop rate (default: the config's control.rate_hz)")
    p.add_argument("--gains", metavar="L1,L2,L3,L4", help="use these gains instead of the configured design")
    p.add_argument("--no-tui", action="store_true", help="no live dashboard; print a summary at the end "
                   "(the default when stdout is not a terminal)")
    p.add_argument("--tui", action="store_true", help="force the live dashboard")
    p.add_argument("--no-rt", action="store_true", help="do not ask for SCHED_FIFO, memory locking or CPU pinning")
    p.add_argument("--cpu", type=int, metavar="N", help="pin the control loop to CPU N (with SCHED_FIFO), with the "
                   "kernel's tty work (as root) and, with --mock, the device: a SAMPLE → COMMAND round trip then waits "
                   "for no other CPU; the logger, the dashboard and (as root) the kernel's housekeeping threads run on "
                   "the others, until the run ends. Default: not pinned, as on a shared "
                   "machine a pinned task cannot move away from a busy CPU")
    p.add_argument("--baud", type=int, default=1_000_000, help="UART baud rate (ignored by USB CDC; default 1000000)")
    p.add_argument("--watchdog-ms", type=int, metavar="MS",
                   help=f"device watchdog (default 20 ms and at least 5 periods; with --mock {MOCK_TIMEOUT_MS:g} ms)")
    p.add_argument("--link-timeout-ms", type=float, metavar="MS",
                   help="no SAMPLE for this long trips the loop (default: safety.link_loss_periods periods; "
                   f"with --mock {MOCK_TIMEOUT_MS:g} ms)")
    p.add_argument("--max-overruns", type=int, metavar="N",
                   help="trip after N commanded ticks in a row miss their deadline (default: "
                   f"safety.max_consecutive_overruns; with --mock {MOCK_TIMEOUT_MS:g} ms worth of ticks)")
    p.add_argument("--summary-json", metavar="FILE", help="also write the summary as JSON to FILE")
    p.add_argument("--foxglove", nargs="?", type=int, const=8765, default=None, metavar="PORT",
                   help="serve the live channels to Foxglove, Lichtblick or any foxglove.websocket.v1 / foxglove.sdk.v1 "
                   "client (Open connection → Foxglove WebSocket, ws://127.0.0.1:PORT, default 8765), from the "
                   "logger process, not the control loop")
    p.add_argument("--foxglove-host", default="127.0.0.1", metavar="ADDR",
                   help="address the live view listens on (default 127.0.0.1, this computer only; 0.0.0.0 for the "
                   "lab's other computers: the stream is not authenticated)")
    m = p.add_argument_group("--mock options (passed to hil-mock)")
    m.add_argument("--mock-effect", action="append", default=[], metavar="NAME.PARAM=VALUE",
                   help="physics the simulated rig has beyond the config, e.g. arm_coulomb.Fc=0.3 (repeatable)")
    m.add_argument("--mock-fault", action="append", default=[], metavar="KIND@T[:DUR]",
                   help="scheduled device fault, e.g. mute@3:100ms, disconnect@5 (repeatable)")
    m.add_argument("--mock-seed", type=int, metavar="N", help="sensor-noise seed of the mock")
    m.add_argument("--mock-initial-theta", type=float, metavar="RAD",
                   help="pendulum angle when the mock starts (default 0.05 rad: arms at once; with --swing-up it "
                   "starts hanging)")
    m.add_argument("--mock-firmware", choices=("python", "c", "board"),
                   help="the mock's device logic: python (default); c, the DAQ firmware's C core built for this "
                        "machine; board, the flashed image on the register-level board model (a dc_motor rig)")
    m.add_argument("--mock-arg", action="append", default=[], metavar="ARG",
                   help="any other hil-mock argument, e.g. --mock-arg=--drop-rate=0.001 (repeatable)")
    p.set_defaults(func=run)


def effective_rig(rig: RigConfig, rate: int | None, mode: str | None, gains: list[float] | None,
                  swing_up: bool = False) -> RigConfig:
    """The rig as this run uses it (what the log records): --rate, --comp, --gains and --swing-up applied."""
    control = rig.control
    if rate is not None:
        control = control.model_copy(update={"rate_hz": float(rate)})
    if gains is not None:
        control = control.model_copy(update={"design": "gains", "gains": list(gains)})
    comp = rig.compensation if mode is None else rig.compensation.model_copy(update={"mode": mode})
    up = rig.swing_up.model_copy(update={"enabled": True}) if swing_up else rig.swing_up
    return rig.model_copy(update={"control": control, "compensation": comp, "swing_up": up})


def check_reads_hanging(rig: RigConfig, flag: str, margin: float) -> None:
    """θ's sensor reads the pendulum hanging (π, ± ``margin``); else one line naming the key."""
    s = rig.sensors
    reach = 32767 * s.theta_rad_per_count
    if not s.theta_wraps and reach < math.pi + margin:
        raise UserError(f"{flag}: rig '{rig.name}' reads θ only up to ±{reach:.3f} rad (sensors.theta_wraps = false) "
                        "and the pendulum hangs at π; set sensors.theta_wraps = true if θ's sensor reads the full turn")


def check_swing_up(rig: RigConfig) -> None:
    """A swing-up needs θ read through hanging (π) and a consistent catch/fall; else one line naming the key."""
    from furuta_rt.controller.swingup import SwingUpDesign

    check_reads_hanging(rig, "--swing-up", rig.swing_up.hanging_tolerance)
    try:
        SwingUpDesign.from_rig(rig)
    except ValueError as err:
        raise UserError(f"--swing-up: {err}") from None


def mock_arguments(args: argparse.Namespace, rig_source: str, rate: int, watchdog_ms: int) -> list[str]:
    out = ["--rig", rig_source, "--rate", str(rate), "--watchdog-ms", str(watchdog_ms)]
    if args.mock_initial_theta is not None:
        out += ["--initial-theta", repr(args.mock_initial_theta)]
    else:
        hanging = args.swing_up or getattr(args, "hanging_experiment", False)
        out += ["--start", "hanging"] if hanging else ["--initial-theta", "0.05"]
    for e in args.mock_effect:
        out += ["--effect", e]
    for f in args.mock_fault:
        out += ["--fault", f]
    if args.mock_seed is not None:
        out += ["--seed", str(args.mock_seed)]
    if args.mock_firmware is not None:
        out += ["--firmware", args.mock_firmware]
    if args.cpu is not None and not args.no_rt:  # the device's thread on the loop's CPU: a round trip then needs no other
        out += ["--cpu", str(args.cpu)]
    return out + list(args.mock_arg)


def _check_log_name(path: str) -> None:
    """The log is an MCAP file: its name says so."""
    if Path(path).suffix.lower() != ".mcap":
        raise UserError(f"--log {path}: the log is an MCAP file; give a name ending in .mcap (a CSV of it: "
                        f"furuta-rt convert LOG.mcap -o {Path(path).with_suffix('.csv').name})")


def run(args: argparse.Namespace) -> int:
    from furuta_rt.runtime.daemon import RunOptions, default_tui, run_daemon

    if not args.mock and not args.port:
        raise UserError("give --port DEV (the rig's DAQ, e.g. /dev/ttyACM0) or --mock (the simulated pendulum)")
    if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
        raise UserError(f"--duration {args.duration:g}: must be a positive number of seconds")
    if args.rate is not None and not 1 <= args.rate <= 10_000:
        raise UserError(f"--rate {args.rate}: must be between 1 and 10000 Hz")
    if args.tui and args.no_tui:
        raise UserError("--tui and --no-tui contradict each other; give one of them")
    if args.log is not None:
        _check_log_name(args.log)
    if args.cpu is not None:
        check_cpu_option(args.cpu)
    claim_outputs([("--log", args.log), ("--summary-json", args.summary_json)], force=args.force)
    has_mock_opts = (args.mock_effect or args.mock_fault or args.mock_arg or args.mock_seed is not None
                     or args.mock_firmware is not None)
    if has_mock_opts and not args.mock:
        raise UserError("--mock-effect/--mock-fault/--mock-seed/--mock-firmware/--mock-arg only apply with --mock")
    if args.comp and args.comp_from:
        raise UserError("--comp and --comp-from contradict each other; give one of them")
    rig = rig_from_args(args)
    gains = parse_gains(args.gains)
    comp_source = ""
    warnings: list[str] = []
    if args.comp_from:
        from furuta_rt.controller.comp_from import compensation_from_report

        found = compensation_from_report(args.comp_from, rig.compensation, rig.name)
        rig = rig.model_copy(update={"compensation": found.compensation})
        comp_source, warnings = found.source, list(found.warnings)
    rig = effective_rig(rig, args.rate, args.comp, gains, args.swing_up)
    if rig.swing_up.enabled:
        check_swing_up(rig)
    args.swing_up = rig.swing_up.enabled  # the mock starts hanging (mock_arguments)
    rate_f = rig.control.rate_hz
    if rate_f != int(rate_f):
        raise UserError(f"control.rate_hz = {rate_f:g}: the device needs a whole number of Hz; pass --rate")
    rate = int(rate_f)
    period_ms = 1000.0 / rate
    default_watchdog = MOCK_TIMEOUT_MS if args.mock else max(20, math.ceil(5 * period_ms))
    watchdog = args.watchdog_ms if args.watchdog_ms is not None else int(default_watchdog)
    if not 1 <= watchdog <= 65535:
        raise UserError(f"--watchdog-ms {watchdog}: must be 1..65535")
    link_ms = rig.safety.link_loss_periods * period_ms
    if args.link_timeout_ms is not None:
        if not args.link_timeout_ms > 0:
            raise UserError(f"--link-timeout-ms {args.link_timeout_ms:g}: must be > 0")
        link_ms = args.link_timeout_ms
    elif args.mock:
        link_ms = max(link_ms, MOCK_TIMEOUT_MS)
    max_overruns = rig.safety.max_consecutive_overruns
    if args.max_overruns is not None:
        if args.max_overruns < 1:
            raise UserError(f"--max-overruns {args.max_overruns}: must be >= 1")
        max_overruns = args.max_overruns
    elif args.mock:
        max_overruns = max(max_overruns, math.ceil(MOCK_TIMEOUT_MS / period_ms))
    plan = _experiment_plan(args, rig, rate)
    args.hanging_experiment = plan is not None and plan.mode == "hanging"  # the mock starts hanging (mock_arguments)
    rig_source = args.config or "thesis"
    opts = RunOptions(
        rig=rig,
        mode=rig.compensation.mode,
        duration=args.duration,
        port=args.port,
        mock_args=mock_arguments(args, rig_source, rate, watchdog) if args.mock else None,
        baud=args.baud,
        watchdog_ms=watchdog,
        link_timeout_s=link_ms * 1e-3,
        max_overruns=max_overruns,
        log_path=args.log,
        foxglove_port=args.foxglove,
        foxglove_host=args.foxglove_host,
        tui=(args.tui or default_tui()) and not args.no_tui,
        realtime=not args.no_rt,
        cpu=args.cpu,
        gains=gains,
        summary_json=args.summary_json,
        force=args.force,
        rig_source=rig_source,
        comp_source=comp_source,
        warnings=warnings,
        experiment=plan,
        experiment_source=args.experiment or "",
    )
    return run_daemon(opts)


def _experiment_plan(args: argparse.Namespace, rig: RigConfig, rate: int) -> Any:
    """--experiment's plan, checked against the rig's |u| and |φ| limits and --duration (one line if not); a hanging
    plan also against --swing-up (the two start differently) and θ's sensor (it must read π)."""
    if not args.experiment:
        return None
    from furuta_rt.experiment.hanging import SWING_LIMIT
    from furuta_rt.experiment.plan import check_plan_limits, load_plan

    plan = load_plan(args.experiment)
    hanging = plan.mode == "hanging"
    if hanging and rig.swing_up.enabled:
        raise UserError(f"--experiment {args.experiment}: a hanging plan runs open loop from the pendulum hanging at "
                        "rest; it cannot follow a swing-up (leave out --swing-up, or set swing_up.enabled = false)")
    if hanging:
        check_reads_hanging(rig, f"--experiment {args.experiment} (hanging)", SWING_LIMIT)
    try:
        check_plan_limits(plan, u_limit=rig.actuator.limit, phi_limit=rig.safety.phi_limit)
    except UserError as err:
        raise UserError(f"--experiment {args.experiment}: {err}") from None
    need = plan.settle_s + plan.duration
    how = "hanging, open loop" if hanging else "of balancing"
    if args.duration is not None and args.duration < need:
        raise UserError(f"--duration {args.duration:g} s is shorter than the plan {args.experiment} "
                        f"({need:.3g} s {how}); leave --duration out to run until the plan ends")
    lines = "; ".join(plan.describe())
    limit = f"; trips beyond |θ − π| = {SWING_LIMIT:g} rad" if hanging else ""
    print(f"furuta-rt: experiment {args.experiment}: {need:.3g} s {how} at {rate} Hz: "
          f"settle {plan.settle_s:g} s; {lines}{limit}", file=sys.stderr, flush=True)
    return plan
