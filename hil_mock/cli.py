"""``hil-mock``: serve the simulated rig's DAQ on a pseudo-terminal until stopped.

    hil-mock --pty [--config FILE] [--effect arm_coulomb.Fc=0.3 ...] [--rate HZ] [--fault reset@3 ...]

Prints exactly one line on stdout, ``hil-mock: serving on /dev/pts/N``, flushed, then serves until
SIGINT/SIGTERM (or ``--duration``, or a ``disconnect`` fault) and prints its statistics on stderr.
SIGUSR1 prints the statistics without stopping; SIGUSR2 resets the device (as ``--fault reset@…``).
Bad input → one line on stderr, exit 2.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import signal
import sys
import threading
from collections.abc import Callable
from pathlib import Path

from firmware_protocol.hostbuild import BuildError
from furuta_rt.cpu_placement import check_cpu_option
from furuta_rt.errors import OneLineParser, UserError
from furuta_rt.io.output import claim_outputs, write_text
from furuta_rt.tomlfile import read_toml
from hil_mock.config import MockConfig, build_config
from hil_mock.device import VirtualDevice
from hil_mock.launch import SERVING_PREFIX


def build_parser() -> argparse.ArgumentParser:
    p = OneLineParser(
        prog="hil-mock",
        description="Simulated Furuta pendulum DAQ speaking firmware_protocol on a pseudo-terminal.",
    )
    p.add_argument("--pty", action="store_true", help="serve on a new pseudo-terminal (the only mode; default)")
    p.add_argument("--mock-config", metavar="FILE", help="mock TOML file (rig, [effects], [device], [faults])")
    p.add_argument("--config", metavar="FILE", help="a rig TOML file, as furuta-rt's --config (the same as --rig); a "
                   "mock TOML given here is read as --mock-config, with a note")
    p.add_argument("--rig", help="rig TOML file or shipped rig (overrides the mock file's 'rig'; default thesis)")
    p.add_argument("--effect", action="append", default=[], metavar="NAME.PARAM=VALUE",
                   help="add an effect, e.g. arm_coulomb.Fc=0.3 (repeatable; overrides the file)")
    p.add_argument("--rate", type=int, metavar="HZ", help="sample rate (default: the rig's control.rate_hz)")
    p.add_argument("--watchdog-ms", type=int, metavar="MS", help="device watchdog (default 20)")
    p.add_argument("--seed", type=int, help="sensor-noise seed (default 0)")
    p.add_argument("--initial-theta", type=float, metavar="RAD", help="pendulum angle at release (default 0.05)")
    p.add_argument("--start", choices=("upright", "hanging"),
                   help="where the pendulum is at release: upright (θ = --initial-theta, default) or hanging at rest "
                   "(θ = π, for a swing-up)")
    p.add_argument("--substep-hz", type=float, metavar="HZ", help="physics substep rate (default 10000)")
    p.add_argument("--pacing", choices=("realtime", "free", "lockstep"), help="default realtime")
    p.add_argument("--spin-us", type=float, metavar="US", help="longest busy-wait before a deadline (default 100)")
    p.add_argument("--priority", choices=("normal", "realtime"),
                   help="realtime (default): SCHED_FIFO for the device thread if permitted, else nice -10")
    p.add_argument("--cpu", type=int, metavar="N", help="pin the device thread to CPU N (furuta-rt run --cpu N "
                   "passes its own: host and device on one CPU; default: not pinned)")
    p.add_argument("--firmware", choices=("python", "c", "board"),
                   help="device logic: c (default), the microcontroller's C core built for this machine; python; or "
                        "board, the flashed image (scripts/build_firmware) on the register-level STM32F401 model")
    p.add_argument("--plant", choices=("compiled", "python"),
                   help="plant integration: compiled (default; C, where it covers the model) or python (the reference "
                   "simulator)")
    p.add_argument("--fault", action="append", default=[], metavar="KIND@T[:DUR]",
                   help="scheduled fault, e.g. stall@2.0:100ms, reset@3, disconnect@5, mute@1:50ms, deaf@1:50ms, "
                        "push@4 (an impulse on the pendulum; push@4:8 = θ̇ jumps 8 rad/s), friction_step@8:Fc=0.5 "
                        "(the arm's Coulomb friction becomes 0.5 N m)")
    p.add_argument("--corrupt-rate", type=float, metavar="P", help="flip a bit in each device→host byte with probability P")
    p.add_argument("--drop-rate", type=float, metavar="P", help="drop each device→host byte with probability P")
    p.add_argument("--rx-corrupt-rate", type=float, metavar="P", help="the same for host→device bytes")
    p.add_argument("--rx-drop-rate", type=float, metavar="P", help="the same for host→device bytes")
    p.add_argument("--delay-ms", type=float, metavar="MS", help="hold outgoing frames this long")
    p.add_argument("--link", metavar="PATH", help="also make PATH a symlink to the pty (removed on exit)")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds of wall time")
    p.add_argument("--stats-json", metavar="FILE", help="write the final statistics as JSON to FILE")
    p.add_argument("--force", action="store_true", help="replace an existing --stats-json FILE (without it an "
                   "existing file is refused, exit 2, before the device starts)")
    p.add_argument("--exit-with-fd", type=int, metavar="FD",
                   help="stop (as on SIGINT) when file descriptor FD, a pipe whose write end the launcher holds, "
                        "reaches end of file: the mock then ends with its launcher, even when that is SIGKILLed")
    return p


def _initial_theta(args: argparse.Namespace) -> float | None:
    if args.start == "hanging":
        if args.initial_theta is not None:
            raise UserError("--start hanging and --initial-theta contradict each other; give one of them")
        return math.pi
    return args.initial_theta


def _config_and_rig(args: argparse.Namespace) -> tuple[str | None, str | None]:
    """(mock TOML, rig) from --mock-config, --config and --rig: ``--config`` names a rig, as everywhere in furuta-rt;
    a mock TOML given there (no [plant] table) is still read as one, and said."""
    if args.config is None:
        return args.mock_config, args.rig
    try:
        is_rig = "plant" in read_toml(args.config, kind="config file")[0]
    except (UserError, OSError):
        is_rig = True  # let the rig loader say what is wrong with it
    if not is_rig:
        if args.mock_config is not None:
            raise UserError(f"--config {args.config} is a mock TOML and --mock-config is given too; give one")
        print(f"hil-mock: note: --config {args.config} is a mock TOML (no [plant]); read as --mock-config "
              "(--config names a rig, as in furuta-rt)", file=sys.stderr, flush=True)
        return args.config, args.rig
    if args.rig is not None:
        raise UserError(f"--config {args.config} and --rig {args.rig} both name the rig; give one")
    return args.mock_config, args.config


def config_from_args(args: argparse.Namespace) -> MockConfig:
    mock_toml, rig = _config_and_rig(args)
    return build_config(
        mock_toml,
        rig=rig,
        effects=args.effect,
        faults=args.fault,
        device={
            "rate_hz": args.rate, "watchdog_ms": args.watchdog_ms, "seed": args.seed,
            "initial_theta": _initial_theta(args), "substep_hz": args.substep_hz, "pacing": args.pacing,
            "spin_us": args.spin_us, "priority": args.priority, "cpu": args.cpu,
            "firmware": args.firmware, "plant": args.plant,
        },
        fault_settings={
            "corrupt_rate": args.corrupt_rate, "drop_rate": args.drop_rate, "rx_corrupt_rate": args.rx_corrupt_rate,
            "rx_drop_rate": args.rx_drop_rate, "delay_ms": args.delay_ms,
        },
    )


def _make_link(link: str, port: str) -> Path:
    path = Path(link)
    if path.is_symlink():
        path.unlink()
    elif path.exists():
        raise UserError(f"--link {link}: exists and is not a symlink; choose another path")
    try:
        path.symlink_to(port)
    except OSError as err:
        raise UserError(f"--link {link}: cannot create the symlink ({err.strerror})") from None
    return path


def _watch_launcher(fd: int, on_gone: Callable[[], None]) -> None:
    """Call ``on_gone`` when the pipe ``fd`` reaches end of file (every write end closed: the launcher is gone)."""
    try:
        os.fstat(fd)
    except OSError:
        raise UserError(f"--exit-with-fd {fd}: not an open file descriptor") from None

    def watch() -> None:
        with contextlib.suppress(OSError):
            while os.read(fd, 64):
                pass
        on_gone()

    threading.Thread(target=watch, name="hil-mock launcher watch", daemon=True).start()


def serve(args: argparse.Namespace) -> int:
    if args.cpu is not None:
        check_cpu_option(args.cpu)
    claim_outputs([("--stats-json", args.stats_json)], force=args.force)
    cfg = config_from_args(args)
    try:
        device = VirtualDevice(cfg)
    except (ValueError, BuildError) as err:
        raise UserError(str(err)) from None
    link = _make_link(args.link, device.port) if args.link else None
    if args.exit_with_fd is not None:
        _watch_launcher(args.exit_with_fd, device.request_stop)

    def on_stop(signum: int, frame: object) -> None:
        device.request_stop()

    def on_usr1(signum: int, frame: object) -> None:
        print(device.stats.summary(), file=sys.stderr, flush=True)

    def on_usr2(signum: int, frame: object) -> None:
        device.reset()

    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, on_stop)
        signal.signal(signal.SIGTERM, on_stop)
        signal.signal(signal.SIGUSR1, on_usr1)
        signal.signal(signal.SIGUSR2, on_usr2)
    timer = threading.Timer(args.duration, device.request_stop) if args.duration else None
    print(f"{SERVING_PREFIX}{device.port}", flush=True)
    try:
        if timer is not None:
            timer.daemon = True
            timer.start()
        device.run()
    finally:
        if timer is not None:
            timer.cancel()
        device.stop()
        if link is not None:
            with contextlib.suppress(OSError):
                link.unlink()
    stats = device.stats
    if args.stats_json:  # the file first: a launcher gone (its stderr pipe closed) must not cost the user the figures
        write_text(args.stats_json, json.dumps(stats.as_dict(), indent=2) + "\n", overwrite=args.force, flag="--stats-json")
    print(stats.summary(), file=sys.stderr, flush=True)
    return 0


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return serve(args)
    except UserError as err:
        print(f"hil-mock: error: {err}", file=sys.stderr)
        return err.exit_code
    except BrokenPipeError:
        with contextlib.suppress(OSError):
            os.close(sys.stdout.fileno())
        return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
