"""Closed-loop simulation: the same Controller.update as the daemon, against the Simulator.

Timing as on the rig (furuta_rt.sim.command_path): the sample of tick k is read, the command computed from it takes
effect command_delay_ticks periods later (the protocol's one-period latency by default); with the effect
``command_latency`` it takes effect that many seconds after the sample instant instead.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from furuta_rt.config import CompMode, RigConfig
from furuta_rt.controller.controller import Controller, Excitation
from furuta_rt.model.coupling import Coupling
from furuta_rt.model.effects import Effects
from furuta_rt.model.rig import RigModel
from furuta_rt.model.sensors import Calibration
from furuta_rt.recording import Recording
from furuta_rt.sim.command_path import CommandPath
from furuta_rt.sim.compiled import fast_simulator
from furuta_rt.sim.simulator import Simulator


def run_closed_loop(
    rig: RigConfig,
    duration: float,
    *,
    effects: Effects | None = None,
    mode: CompMode | None = None,
    gains: np.ndarray | list[float] | None = None,
    seed: int = 0,
    x0: tuple[float, float, float, float] = (0.05, 0.0, 0.0, 0.0),
    substep_hz: float = 10_000.0,
    reference: np.ndarray | None = None,
    host_calibration: Calibration | None = None,
    coupling: Coupling | None = None,
    excitation: Excitation | None = None,
    simulator: Callable[..., Simulator] = fast_simulator,
) -> Recording:
    """Simulate ``duration`` s of balancing. ``reference``: optional arm-angle reference per tick
    (added to φ as u = L·(x − x_ref)), used to excite the loop. ``host_calibration``: the counts → SI conversion the
    host uses when it differs from the DAQ's (a sensor scale error; default: the rig's own). ``coupling``: a compliant
    rotor–arm coupling (furuta_rt.model.coupling; default none: eq. 4's rigid arm). ``excitation``: a designed
    experiment's plan at the control rate (furuta_rt.experiment.plan), stepped by the controller as on the rig.
    ``simulator``: the plant (Simulator's constructor); by default the compiled plant where it covers the model
    (furuta_rt.sim.compiled: the same substeps in C, the same recording), else the Python Simulator."""
    model = RigModel.from_config(rig, effects)
    if coupling is not None:
        model = dataclasses.replace(model, coupling=coupling)
    sim = simulator(model, rig.control.rate_hz, substep_hz, seed=seed, x0=x0)
    ctrl = Controller.from_rig(rig, mode=mode, gains=gains)
    ctrl.excitation = excitation
    commands = CommandPath(sim, rig.control.command_delay_ticks)
    n = round(duration * rig.control.rate_hz)
    cols = {k: np.empty(n) for k in (
        "t", "theta", "theta_dot", "phi", "u", "u_lin", "u_comp", "phi_dot_hat",
        "true_theta", "true_theta_dot", "true_phi", "true_phi_dot", "friction",
    )}
    for k in range(n):
        m = sim.measure(host_calibration)
        if reference is not None:
            m.phi -= reference[k]
        out = ctrl.update(m)
        if reference is not None:
            m.phi += reference[k]
        th, thd, ph, phd = sim.state
        row = (m.t, m.theta, m.theta_dot, m.phi, out.u, out.u_lin, out.u_comp, out.phi_dot_hat,
               th, thd, ph, phd, sim.arm_friction_torque)
        for col, value in zip(cols.values(), row, strict=True):
            col[k] = value
        commands.send_and_advance(out.u)
    return Recording(
        t=cols.pop("t"), theta=cols.pop("theta"), phi=cols.pop("phi"), u=cols.pop("u"),
        theta_dot=cols.pop("theta_dot"), extra=cols,
        meta={"rig": rig.name, "mode": mode or rig.compensation.mode, "seed": seed},
    )
