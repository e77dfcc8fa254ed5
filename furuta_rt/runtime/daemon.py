"""`furuta-rt run` end to end: device (or hil_mock), logger and dashboard processes, the loop, the summary.

Process layout (multiprocessing 'spawn': children start from a clean interpreter):

    control (this process)  read → update → write at the device's rate; gc frozen; SCHED_FIFO,
                            mlockall and CPU affinity when permitted
    logger                  MCAP writing, fed tick batches through a bounded queue on a pipe (no named
                            semaphores: nothing is left in /dev/shm whatever kills the group); with
                            --foxglove also the live view (Foxglove WebSocket), from the same items
    dashboard               rich Live view, fed ≤ 10 snapshots/s (only with a terminal)
    hil-mock (--mock)       the simulated DAQ on a pseudo-terminal

Start-up order matters: the device handshake comes last, right before the first tick, because the
pendulum (real or simulated) starts moving when the device starts streaming.

Exit codes: 0 the duration was reached or the operator stopped the run (any of signals.STOP_SIGNALS),
with u = 0 and STOP sent first, the log closed and the summary written; 1 the supervisor tripped (reason
printed); 2 user error (one line); 3 the run ended but the log it was asked for is incomplete (the logger
could not write: disk full, ...); 4 the run ended without ever balancing and was not stopped by the
operator (a script must not take it for success); 128 + signum: interrupted during start-up.
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import dataclasses
import ipaddress
import json
import multiprocessing
import multiprocessing.connection
import os
import signal
import socket
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from firmware_protocol import DEFAULT_WATCHDOG_MS
from furuta_rt.config import RigConfig
from furuta_rt.errors import UserError
from furuta_rt.io.locks import refuse_if_being_written
from furuta_rt.io.mcap_log import run_metadata
from furuta_rt.io.output import probe_writable, write_text
from furuta_rt.runtime import signals as stop_signals
from furuta_rt.runtime.channel import Channel, Flag
from furuta_rt.runtime.design_process import DesignProcess
from furuta_rt.runtime.hardware import DeviceInfo, SerialHardware
from furuta_rt.runtime.logger import LogSetup, logger_process
from furuta_rt.runtime.rt import CONTROL_THREAD_STACK, keep_off_loop_cpu, release_cpu_work, setup_realtime
from furuta_rt.runtime.summary import format_summary, mock_injections, summary_dict

LOG_QUEUE_BATCHES = 200  # 20 s of ticks at 10 batches/s before the loop starts dropping
CHILD_START_TIMEOUT_S = 60.0
EXIT_OK, EXIT_TRIPPED, EXIT_USER_ERROR, EXIT_LOG_INCOMPLETE, EXIT_NEVER_BALANCED = 0, 1, 2, 3, 4


@dataclass
class RunOptions:
    rig: RigConfig  # effective: --rate and --comp already applied
    mode: str
    duration: float | None = None
    port: str | None = None
    mock_args: list[str] | None = None  # None: a real device on ``port``
    baud: int = 1_000_000
    watchdog_ms: int = DEFAULT_WATCHDOG_MS
    link_timeout_s: float = 0.004  # no SAMPLE for this long = link loss
    max_overruns: int | None = None  # None: the rig's safety.max_consecutive_overruns
    log_path: str | None = None
    tui: bool = False
    realtime: bool = True
    cpu: int | None = None  # pin the control loop to this CPU (opt-in)
    gains: list[float] | None = None
    summary_json: str | None = None
    force: bool = False  # an existing --log or --summary-json file may be replaced (the CLI refused them otherwise)
    foxglove_port: int | None = None  # serve the live view (from the logger process) on this port
    foxglove_host: str = "127.0.0.1"  # ... on this address (another computer of the lab: 0.0.0.0)
    rig_source: str = "thesis"
    warnings: list[str] = field(default_factory=list)
    comp_source: str = ""  # where the compensation's parameters came from (--comp-from), in words
    experiment: Any = None  # a designed experiment's plan (furuta_rt.experiment.plan.Plan): balancing or hanging
    experiment_source: str = ""  # its file


def _say(message: str) -> None:
    print(f"furuta-rt: {message}", file=sys.stderr, flush=True)


def _check_log_path(path: str) -> None:
    """The log can be written (nothing is created or truncated here: the logger opens the file when the
    device has answered, so a run that never starts replaces nothing)."""
    if Path(path).is_dir():
        raise UserError(f"--log {path} is a directory; give a file name such as run.mcap")
    refuse_if_being_written(path, "--log")  # --force replaces a finished log, never one a run is writing
    probe_writable(path, "the log")


def _check_port_free(port: int, host: str) -> None:
    """The live view's port can be bound (it is bound for real by the logger process)."""
    if not 1 <= port <= 65535:
        raise UserError(f"--foxglove={port}: a TCP port is 1..65535")
    try:
        family = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0][0]
    except OSError as err:
        raise UserError(f"--foxglove-host {host}: not an address of this computer ({err.strerror})") from None
    with socket.socket(family, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, port))
        except OSError as err:
            raise UserError(f"--foxglove={port}: cannot listen on {host}:{port} ({err.strerror}); "
                            "is another run or bridge serving there? give another port, e.g. --foxglove=8766") from None


def _live_url(opts: RunOptions) -> str:
    return f"ws://{opts.foxglove_host}:{opts.foxglove_port}"


def _ticks_on_disk(path: str) -> int | None:
    """Ticks a reader recovers from the log as it is on disk (None if it cannot be read at all)."""
    from furuta_rt.io.mcap_read import read_log

    try:
        return read_log(path, timing=False).n_ticks
    except Exception:  # an unreadable remnant: the summary says so instead
        return None


def _check_device(info: DeviceInfo, rig: RigConfig, warnings: list[str]) -> None:
    """Refuse a device that cannot run this rig; warn where its calibration differs from the config."""
    bad = info.implausible()
    if bad:
        raise UserError(f"the device's HELLO_ACK is not usable: {bad}; check the firmware")
    reset = info.reset_warning()
    if reset:
        warnings.append(reset)
    if info.actuator_kind != rig.actuator.kind:
        raise UserError(f"the device drives a {info.actuator_kind} actuator but rig '{rig.name}' is configured "
                        f"for '{rig.actuator.kind}'; use the matching --config")
    if not info.full_scale > 0:
        raise UserError(f"the device reports actuator full scale {info.full_scale}; check the firmware")
    if rig.actuator.limit > info.full_scale:
        warnings.append(f"actuator limit {rig.actuator.limit:g} exceeds the device full scale "
                        f"{info.full_scale:g}: commands beyond it are clipped by the device")
    cal, s = info.calibration, rig.sensors
    if cal.phi_counts_per_rev != s.encoder_counts_per_rev:
        warnings.append(f"device encoder has {cal.phi_counts_per_rev} counts/rev, the config says "
                        f"{s.encoder_counts_per_rev}; using the device's")
    for name, dev, cfg in (("theta_rad_per_count", cal.theta_rad_per_count, s.theta_rad_per_count),
                           ("theta_dot_rad_s_per_count", cal.theta_dot_rad_s_per_count, s.theta_dot_rad_s_per_count)):
        if abs(dev - cfg) > 1e-6 * abs(cfg):
            warnings.append(f"device {name} = {dev:.6g} differs from the config's {cfg:.6g}; using the device's")


class _Children:
    """The logger and dashboard processes and their queues."""

    def __init__(self) -> None:
        self.ctx = multiprocessing.get_context("spawn")
        self.log_q: Any = None
        self.log_failed: Any = None
        self.log_opened: Any = None
        self.logger: Any = None
        self.dash_q: Any = None
        self.dashboard: Any = None
        self.live_failed: Any = None
        self.logger_death: str | None = None  # how the logger died during the run (None: it did not)
        self._closing = False

    def spawn_logger(self, setup: LogSetup) -> None:
        """Start the logger process (returns at once; ``wait_logger`` waits for it to be ready)."""
        self.log_q = Channel(LOG_QUEUE_BATCHES)  # pipes, not multiprocessing's named semaphores (channel.py)
        self._ready = Flag()
        self.log_failed = Flag()
        self.log_opened = Flag()
        self.live_failed = Flag() if setup.foxglove_port is not None else None
        proc = self.ctx.Process(target=logger_process,
                                args=(setup, self.log_q, self._ready, self.log_failed, self.log_opened, self.live_failed),
                                name="furuta-rt-logger")
        proc.start()
        self.logger = proc
        self._log_path = setup.path

    def wait_logger(self) -> None:
        """Wait for the logger to be ready; a logger that dies meanwhile is said at once, not after the timeout."""
        if self.logger is None:
            return
        end = time.monotonic() + CHILD_START_TIMEOUT_S
        while not self._ready.wait(0.1):
            if not self.logger.is_alive():
                raise UserError(f"the logger process died during start-up (exit code {self.logger.exitcode}; "
                                f"log {self._log_path}); nothing was recorded")
            if time.monotonic() > end:
                raise UserError(f"the logger process did not start within {CHILD_START_TIMEOUT_S:g} s (log {self._log_path})")

    def watch_logger(self, say: Callable[[str], None]) -> None:
        """From now on a logger that dies before it is told to close is said at once (a thread waiting on its
        process sentinel: nothing in the loop), and the log is then judged incomplete."""
        proc = self.logger
        if proc is None:
            return

        def watch() -> None:
            multiprocessing.connection.wait([proc.sentinel])
            if self._closing:
                return
            proc.join(1.0)
            self.logger_death = _death(proc.exitcode)
            lost = [f"the log {self._log_path} ends at its last complete chunk"] if self._log_path else []
            lost += ["the live view stops"] if self.live_failed is not None else []
            say(f"error: the logger process died ({self.logger_death}); {' and '.join(lost)}; the loop goes on")

        threading.Thread(target=watch, name="logger watch", daemon=True).start()

    def start_dashboard(self, info: Any) -> None:
        from furuta_rt.runtime.dashboard import dashboard_process

        self.dash_q = Channel(2)
        proc = self.ctx.Process(target=dashboard_process, args=(self.dash_q, info), name="furuta-rt-dashboard")
        proc.start()
        keep_off_loop_cpu(proc.pid)  # started from the pinned thread: it would inherit the loop's CPU
        self.dashboard = proc

    def stop_dashboard(self) -> None:
        if self.dashboard is None:
            return
        with contextlib.suppress(Exception):  # full or broken: terminated below
            self.dash_q.put(None, timeout=1.0)
        self.dashboard.join(3.0)
        if self.dashboard.is_alive():
            self.dashboard.terminate()
        self.dash_q.cancel_join_thread()  # what it did not take must not hold this process at exit
        self.dashboard = None

    def close_logger(self, summary: str) -> bool:
        """Send "close" and wait for the file to be finished; True if it was, complete."""
        if self.logger is None:
            return True
        self._closing = True
        ok = self.logger.is_alive()  # a dead logger takes nothing more (its queue may be full: no 10 s wait)
        try:
            if ok:
                self.log_q.put(("close", summary), timeout=10.0)
        except Exception:  # full (a stuck logger): judged below
            ok = False
        self.logger.join(30.0)
        if self.logger.is_alive():
            self.logger.terminate()
            ok = False
        ok = ok and self.logger.exitcode == 0 and not self.log_failed.is_set()
        self.log_q.cancel_join_thread()  # batches a dead logger never took must not hang our exit
        self.logger = None
        return ok


def _death(exitcode: int | None) -> str:
    """How a child process ended, from its exit code (negative: the signal that killed it)."""
    if exitcode is None:
        return "it stopped answering"
    if exitcode < 0:
        try:
            return f"killed by {signal.Signals(-exitcode).name}"
        except ValueError:
            return f"killed by signal {-exitcode}"
    return f"exit code {exitcode}"


def _start_mock(args: list[str]) -> tuple[Any, str]:
    try:
        from hil_mock import MockStartError, start_mock_subprocess
    except ImportError as err:  # pragma: no cover - hil_mock ships with furuta-rt
        raise UserError(f"--mock needs the hil_mock package ({err})") from None
    try:
        return start_mock_subprocess(args)
    except MockStartError as err:
        raise UserError(f"--mock: {err}") from None


def _stop_mock(proc: Any) -> str:
    from hil_mock import stop_mock_subprocess

    return stop_mock_subprocess(proc)


def _limits(opts: RunOptions, rate: int) -> Any:
    from furuta_rt.runtime.supervisor import SupervisorLimits

    swing = None
    if opts.experiment is not None and opts.experiment.mode == "hanging":  # the experiments' modules only then
        from furuta_rt.experiment.hanging import SWING_LIMIT as swing
    limits = SupervisorLimits.from_config(opts.rig.safety, rate, opts.rig.swing_up, hanging_swing=swing)
    if opts.max_overruns is not None:
        limits = dataclasses.replace(limits, max_consecutive_overruns=opts.max_overruns)
    return limits


def _limits_text(opts: RunOptions, rate: int) -> str:
    lim = _limits(opts, rate)
    theta = f"|θ − π| < {lim.swing_limit:g} rad" if lim.hanging else f"|θ| < {lim.theta_limit:g} rad"
    return (f"{theta}, |φ| < {lim.phi_limit:g} rad, |u| ≤ {opts.rig.actuator.limit:g}, "
            f"link timeout {opts.link_timeout_s * 1e3:g} ms, "
            f"device watchdog {opts.watchdog_ms} ms, trip after {lim.max_consecutive_overruns} overruns in a row")


def _compensation_summary(opts: RunOptions, ctrl: Any) -> dict[str, Any]:
    """What the summary says about the compensation: where its parameters came from, the adaptive estimate."""
    adaptive = ctrl.compensator.adaptive
    return {"comp_source": opts.comp_source, "fc_hat": None if adaptive is None else adaptive.fc_hat}


def run_daemon(opts: RunOptions) -> int:
    """Run one session; returns the exit code (UserError propagates for exit 2; ``Interrupted`` for a stop
    signal during start-up). Every stop signal (``signals.STOP_SIGNALS``) is handled for the whole run."""
    guard = stop_signals.RunGuard()
    old = stop_signals.install(guard)
    stack = threading.stack_size(CONTROL_THREAD_STACK)  # mlockall locks a thread's whole stack (8 MB by default)
    try:
        return _run_session(opts, guard)
    finally:
        threading.stack_size(stack)
        stop_signals.restore(old)


def _run_session(opts: RunOptions, guard: stop_signals.RunGuard) -> int:
    rig = opts.rig
    rate = int(rig.control.rate_hz)
    warnings = list(opts.warnings)
    if opts.log_path:
        _check_log_path(opts.log_path)
    if opts.foxglove_port is not None:
        _check_port_free(opts.foxglove_port, opts.foxglove_host)
    children = _Children()
    mock_start: concurrent.futures.Future | None = None
    mock_proc = None
    hw: SerialHardware | None = None
    result = None
    ctrl = None
    mock_stats = ""
    log_ok = True
    design: DesignProcess | None = None
    # a stop signal during start-up raises Interrupted (exit 128 + signum) so the cleanup below runs and
    # no hil-mock is left behind; from the loop on it is an operator stop
    try:
        # start-up in parallel: the controller's design (a helper process: scipy stays out of this one), the
        # logger process, hil-mock (a few seconds of imports each) and, here, the loop's own imports; the device
        # handshake comes last, right before the first tick
        if opts.mock_args is None:  # a real port: missing, busy or not permitted is said at once, before any helper
            assert opts.port is not None
            hw = SerialHardware(opts.port, opts.baud)
            hw.open()
        design = DesignProcess(rig, opts.gains)
        if opts.log_path or opts.foxglove_port is not None:
            children.spawn_logger(LogSetup(path=opts.log_path, rig=rig, foxglove_port=opts.foxglove_port,
                                           foxglove_host=opts.foxglove_host,
                                           replace=opts.force))
        if opts.mock_args is not None:
            pool = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="mock-start")
            mock_start = pool.submit(_start_mock, opts.mock_args)
            pool.shutdown(wait=False)
        from furuta_rt.controller.controller import Controller
        from furuta_rt.runtime.loop import ControlLoop, LoopSettings
        from furuta_rt.runtime.supervisor import Supervisor

        ctrl = Controller.from_rig(rig, mode=opts.mode, design=design.result())  # type: ignore[arg-type]
        if opts.experiment is not None:
            from furuta_rt.experiment.plan import Excitation

            ctrl.excitation = Excitation(opts.experiment, rate)
        limits = _limits(opts, rate)
        sup = Supervisor(limits)
        port = opts.port
        if mock_start is not None:
            mock_proc, port = mock_start.result()
        assert port is not None
        if hw is None:
            hw = SerialHardware(port, opts.baud)
            hw.open()
        warnings += hw.warnings
        children.wait_logger()
        children.watch_logger(_say)
        if children.live_failed is not None and children.live_failed.is_set():  # lost the port to another program
            raise UserError(f"--foxglove={opts.foxglove_port}: the live view cannot listen on {opts.foxglove_host}:"
                            f"{opts.foxglove_port} ({children.live_failed.note}): another run or bridge took the port after "
                            "this run found it free; the run did not start. Give another port, e.g. --foxglove=8766")
        if opts.foxglove_port is not None:
            from furuta_rt.runtime.live import LAYOUT_PATH
            from furuta_rt.runtime.live_door import CLIENTS, SUBPROTOCOLS

            _say(f"live view on {_live_url(opts)} (Foxglove: Open connection → Foxglove WebSocket; "
                 f"layout {LAYOUT_PATH}); serves {' and '.join(SUBPROTOCOLS)} ({CLIENTS})")
            if not ipaddress.ip_address(socket.getaddrinfo(opts.foxglove_host, None)[0][4][0]).is_loopback:
                _say(f"warning: the live view listens on {opts.foxglove_host}:{opts.foxglove_port}: anyone who can "
                     "reach this computer can watch the run (the stream is not authenticated or encrypted)")
        if children.log_q is not None:  # the first put starts the queue's feeder thread: not in a tick, and before
            # the loop's thread is pinned (a thread inherits its creator's CPUs)
            children.log_q.put(("event", (time.time_ns(), "INFO", f"connecting to {port} at {rate} Hz")))
        applied, rt_warnings = setup_realtime(opts.realtime, cpu=opts.cpu)
        if children.logger is not None:
            keep_off_loop_cpu(children.logger.pid)
        warnings += rt_warnings
        sys.setswitchinterval(1e-4)  # a queue feeder thread must give the GIL back quickly
        for w in warnings:
            _say(f"warning: {w}")
        if opts.tui:
            from furuta_rt.runtime.dashboard import DashboardInfo

            children.start_dashboard(DashboardInfo(
                title=f"furuta-rt run — {rig.name}, {opts.mode}, {rate} Hz", log_path=opts.log_path,
                arm_theta=limits.arm_theta, theta_limit=limits.theta_limit, phi_limit=limits.phi_limit,
                live_url=_live_url(opts) if opts.foxglove_port is not None else None,
                u_unit="V" if rig.actuator.kind == "dc_motor" else "N m"))
        info = hw.handshake(rate, opts.watchdog_ms)
        late_warnings: list[str] = []
        _check_device(info, rig, late_warnings)
        if not opts.tui:  # with the dashboard they show as its events
            for w in late_warnings:
                _say(f"warning: {w}")
        loop = ControlLoop(
            hw, ctrl, sup,
            LoopSettings(rate_hz=rate, duration=opts.duration, link_timeout_s=opts.link_timeout_s,
                         batch_ticks=max(1, rate // 10), snapshot_ticks=max(1, rate // 10)),
            full_scale=info.full_scale, theta_dot_offset_counts=info.theta_dot_offset_counts,
            calibration=info.calibration, log=children.log_q, dashboard=children.dash_q, mode=opts.mode,
            swing_up=rig.swing_up if rig.swing_up.enabled else None,
            on_event=None if opts.tui else (lambda level, msg: _say(msg if level == "INFO" else f"{level.lower()}: {msg}")),
        )
        if children.log_q is not None:
            run_meta = run_metadata(
                opts.mode, list(ctrl.gains), rate, port=port, rig_source=opts.rig_source, host=socket.gethostname(),
                mock=json.dumps(opts.mock_args), duration=str(opts.duration), started=time.strftime("%Y-%m-%dT%H:%M:%S%z"),
                link_timeout_ms=f"{opts.link_timeout_s * 1e3:g}", watchdog_ms=str(opts.watchdog_ms),
                max_consecutive_overruns=str(limits.max_consecutive_overruns),
                **({"comp_source": opts.comp_source} if opts.comp_source else {}),
                swing_up=str(rig.swing_up.enabled).lower(),
                **({"experiment": opts.experiment_source} if opts.experiment is not None else {}),
            )
            children.log_q.put_nowait(("open", info.metadata(), run_meta))
            if opts.experiment is not None:
                from furuta_rt.experiment.plan import METADATA_NAME

                children.log_q.put_nowait(("metadata", METADATA_NAME, {
                    "source": opts.experiment_source, "plan": opts.experiment.to_toml()}))
        loop.event("INFO", f"device {info.ack.device_id:#010x} firmware {info.firmware} at {port}, {info.rate_hz} Hz, "
                   f"watchdog {info.watchdog_ms} ms, last start: {info.reset_cause}; {', '.join(applied)}")
        for w in warnings + late_warnings:  # printed above: logged here (the dashboard shows the log's events)
            loop.event("WARNING", w, show=False)
        warnings += late_warnings
        guard.forward_to(loop.request_stop)
        result = loop.run()
    finally:
        # shutting down: a second Ctrl-C (or a SIGTERM burst, a hang-up) must not cut the log or the summary
        guard.shutting_down()
        if design is not None:
            design.close()
        if hw is not None:
            hw.stop()
            hw.close()
        for w in release_cpu_work():
            _say(f"warning: {w}")
        children.stop_dashboard()
        comp = _compensation_summary(opts, ctrl) if ctrl is not None else {}
        summary = "" if result is None else format_summary(result, rate_hz=rate, mode=opts.mode, rig=rig.name,
                                                            log_path=opts.log_path, limits=_limits_text(opts, rate),
                                                            injected=mock_injections(opts.mock_args), **comp)
        log_ok = children.close_logger(summary) or not opts.log_path  # a live view only: no file to be incomplete
        if mock_proc is None and mock_start is not None:  # start-up failed elsewhere: do not leave it running
            with contextlib.suppress(Exception):
                mock_proc = mock_start.result(timeout=60)[0]
        if mock_proc is not None:
            mock_stats = _stop_mock(mock_proc)
    log_ticks = None
    if not log_ok and opts.log_path and result is not None:  # say what the file holds, not what was sent to it
        # a file this run never opened (another run created it first) holds none of this run's ticks
        log_ticks = _ticks_on_disk(opts.log_path) if children.log_opened.is_set() else 0
        summary = format_summary(result, rate_hz=rate, mode=opts.mode, rig=rig.name, log_path=opts.log_path,
                                 limits=_limits_text(opts, rate), log_ticks=log_ticks, log_incomplete=True,
                                 injected=mock_injections(opts.mock_args), **comp)
    code = _outcome(result, log_ok, opts, children.logger_death)
    # the outcome first: an output that fails now (a closed terminal, a broken pipe, an unwritable
    # --summary-json) is one more line, never a different exit code for the run
    lost = _emit(lambda: print(summary, flush=True))
    if mock_stats.strip():
        lost = lost or _emit(lambda: print("\n".join("  " + line for line in mock_stats.strip().splitlines()), flush=True))
    if opts.summary_json:
        data = summary_dict(result, rate_hz=rate, mode=opts.mode, rig=rig.name, log_path=opts.log_path, warnings=warnings,
                            injected=mock_injections(opts.mock_args),
                            log_ticks=log_ticks if not log_ok else result.ticks if opts.log_path else None, **comp)
        try:
            write_text(opts.summary_json, json.dumps(data, indent=1) + "\n", overwrite=opts.force, flag="--summary-json")
        except (UserError, OSError) as err:
            why = str(err) if isinstance(err, UserError) else (err.strerror or str(err)).lower()
            _emit(lambda: _say(f"error: --summary-json {opts.summary_json} not written: {why}"))
            code = code or EXIT_USER_ERROR
    if lost:
        _emit(lambda: _say("error: the summary could not be printed (stdout closed or a broken pipe)"))
    return code


def _emit(write: Callable[[], None]) -> bool:
    """Run one output step; True if the output is gone (closed terminal, broken pipe). Never raises."""
    try:
        write()
    except OSError:
        with contextlib.suppress(OSError, ValueError):  # later writes to it must not fail at exit either
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return True
    return False


def _outcome(result: Any, log_ok: bool, opts: RunOptions, logger_death: str | None = None) -> int:
    """The run's exit code, said on stderr: trip 1, incomplete log 3, never balanced 4 (not after an operator
    stop: stopping a run on purpose is not an error), else 0."""
    if result.end == "trip":
        return EXIT_TRIPPED
    if not log_ok:
        why = f"the logger process died during the run ({logger_death})" if logger_death else "the logger could not finish it"
        _emit(lambda: _say(f"error: the log {opts.log_path} is incomplete: {why} (exit {EXIT_LOG_INCOMPLETE})"))
        return EXIT_LOG_INCOMPLETE
    if result.balancing_ticks > 0 or result.open_loop_ticks > 0:  # a hanging experiment never balances
        return EXIT_OK
    rig = opts.rig
    hanging = opts.experiment is not None and opts.experiment.mode == "hanging"
    where = ("the swing-up never reached the catch region" if rig.swing_up.enabled
             else f"it never came within the arming window about hanging (|θ − π| < {rig.safety.arm_theta:g} rad)"
             if hanging else f"it never came within the arming window (|θ| < {rig.safety.arm_theta:g} rad)")
    if result.end == "operator_stop":
        _emit(lambda: _say(f"the pendulum did not balance before the operator stop: {where}"))
        return EXIT_OK
    _emit(lambda: _say(f"error: the pendulum never balanced: {where}; exit {EXIT_NEVER_BALANCED}"))
    return EXIT_NEVER_BALANCED


def default_tui() -> bool:
    """The dashboard is on when stdout is a terminal (and TERM is not 'dumb')."""
    return sys.stdout.isatty() and os.environ.get("TERM", "") != "dumb"
