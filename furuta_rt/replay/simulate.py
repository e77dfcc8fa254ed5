"""A log as the daemon writes it, from the simulator: for tests, demos and the replay benchmark.

Each tick: the simulator's SAMPLE (raw counts) → SI with the rig's calibration → the supervisor state →
Controller.reset/update/hold → the command takes effect with the rig's command timing (furuta_rt.sim.command_path,
as in furuta_rt.sim.closed_loop). The supervisor is a fixed script: ``idle`` s of idle (hold, u = 0), then
balancing, re-armed (reset) at each time in ``rearm``, tripped (hold) when |θ| exceeds the safety limit.
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import numpy as np

from firmware_protocol import StatusFlags
from furuta_rt.config import CompMode, RigConfig
from furuta_rt.controller.controller import Controller, Measurement, design_gains
from furuta_rt.io.log_schema import device_time_base
from furuta_rt.io.mcap_log import LogWriter, run_metadata
from furuta_rt.model.effects import Effects
from furuta_rt.model.rig import RigModel
from furuta_rt.sim.command_path import CommandPath
from furuta_rt.sim.simulator import Simulator


def simulate_log(
    path: str | Path,
    rig: RigConfig,
    duration: float,
    *,
    mode: CompMode | None = None,
    gains: list[float] | np.ndarray | None = None,
    effects: Effects | None = None,
    seed: int = 0,
    x0: tuple[float, float, float, float] = (0.02, 0.0, 0.0, 0.0),
    idle: float = 0.1,
    rearm: tuple[float, ...] = (),
    substep_hz: float = 10_000.0,
    flush_every: float | None = None,
) -> Path:
    """Write ``duration`` s of a simulated run as a log; returns ``path``. ``flush_every`` (s): end a
    chunk at that period (as the daemon does, so a kill loses at most that much)."""
    rate = rig.control.rate_hz
    model = RigModel.from_config(rig, effects)
    sim = Simulator(model, rate, max(substep_hz, rate), seed=seed, x0=x0)
    commands = CommandPath(sim, rig.control.command_delay_ticks)
    mode = mode or rig.compensation.mode
    L = design_gains(rig) if gains is None else np.asarray(gains, dtype=float)
    ctrl = Controller.from_rig(rig, mode=mode, gains=L)
    cal = model.calibration
    n = round(duration * rate)
    idle_ticks = round(idle * rate)
    rearm_ticks = {round(s * rate) for s in rearm}
    flush_ticks = round(flush_every * rate) if flush_every else 0
    limit = rig.safety.theta_limit
    run = run_metadata(mode, L, rate, source="simulation", seed=str(seed), effects=json.dumps(
        effects.model_dump(exclude_none=True) if effects else {}))
    device = {k: repr(v) for k, v in dataclasses.asdict(cal).items()}  # the HELLO_ACK calibration
    state = "idle"
    wall0 = time.time_ns()  # the simulated device clock mapped to the wall clock at the start (log_schema's time base)
    with LogWriter(path, rig, run, device) as w:
        w.time_base(device_time_base(wall0, 0, "the start of the simulation"))
        w.event(wall0, "INFO", "simulated run started")
        for k in range(n):
            s = sim.sample()
            th, thd, ph = cal.to_si(s.theta_adc, s.theta_dot_adc, s.phi_count)
            m = Measurement(sim.t, th, thd, ph)
            reset = False
            if (k == idle_ticks and state == "idle") or (k in rearm_ticks and state == "balancing"):
                state, reset = "balancing", True
                ctrl.reset(ph)
            if state == "balancing" and abs(th) > limit:
                state = "tripped"
                w.event(wall0 + round(sim.t * 1e9), "WARNING", f"tripped: |theta| = {abs(th):.3f} > {limit}")
            if state == "balancing":
                out = ctrl.update(m)
                u, u_lin, u_comp, phd, sat = out.u, out.u_lin, out.u_comp, out.phi_dot_hat, out.saturated
            else:
                u, u_lin, u_comp, phd, sat = 0.0, 0.0, 0.0, ctrl.hold(m), False
            status = (StatusFlags.ENABLED if state == "balancing" else 0) | (StatusFlags.ADC_OVERRANGE if s.overrange else 0)
            ns = wall0 + round(sim.t * 1e9)
            w.tick(ns, {
                "seq": k, "t": sim.t, "theta_adc": s.theta_adc, "theta_dot_adc": s.theta_dot_adc,
                "phi_count": s.phi_count, "status": int(status), "theta": th, "theta_dot": thd, "phi": ph,
                "phi_dot_hat": phd, "u": u, "u_lin": u_lin, "u_comp": u_comp, "saturated": sat,
                "state": state, "reset": reset, "mode": mode,
            }, {
                "seq": k, "period_us": 1e6 / rate, "read_us": 0.0, "update_us": 0.0, "write_us": 0.0,
                "latency_us": 0.0, "lateness_us": 0.0, "overruns": 0, "seq_gaps": 0, "crc_errors": 0,
                "dropped_log_messages": 0,
            })
            if flush_ticks and (k + 1) % flush_ticks == 0:
                w.flush()
            commands.send_and_advance(u)
    return Path(path)
