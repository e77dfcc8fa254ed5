"""A simulated swing-up from hanging at rest: the same Controller.update as the daemon (its swing-up on), against the
Simulator, timed as run_closed_loop times it (furuta_rt.sim.command_path). What the HIL tests and the
benchmark compare the real-time runs with.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from furuta_rt.config import RigConfig
from furuta_rt.controller.controller import Controller
from furuta_rt.model.effects import Effects
from furuta_rt.model.rig import RigModel
from furuta_rt.sim.command_path import CommandPath
from furuta_rt.sim.compiled import fast_simulator


@dataclass(frozen=True)
class SwingUpRun:
    first_catch_s: float  # s from the start of the swing-up to the first catch (nan: never)
    recatch_s: float  # s from the push to the next catch (nan: no push, or never)
    falls: int
    peak_phi: float  # max |φ|, rad
    peak_u: float  # max |u|, command units
    t: np.ndarray
    theta: np.ndarray  # wrapped to [−π, π)
    phi: np.ndarray
    u: np.ndarray
    swinging: np.ndarray
    true_state: np.ndarray  # (n, 4): the simulator's x = [θ, θ̇, φ, φ̇] at each sample, θ unwrapped


def swing_up_rig(rig: RigConfig) -> RigConfig:
    """``rig`` with its swing-up turned on (what ``run --swing-up`` does)."""
    return rig.model_copy(update={"swing_up": rig.swing_up.model_copy(update={"enabled": True})})


def simulate_swing_up(rig: RigConfig, duration: float, *, effects: Effects | None = None, seed: int = 0,
                      push_at: float | None = None, push: float = 0.0, substep_hz: float = 5000.0) -> SwingUpRun:
    """Swing up from θ = π at rest for ``duration`` s; ``push_at``: θ̇ jumps by ``push`` rad/s then (0: 2·√(ε/α), as
    hil_mock's push fault)."""
    rig = swing_up_rig(rig)
    model = RigModel.from_config(rig, effects)
    sim = fast_simulator(model, rig.control.rate_hz, substep_hz, seed=seed, x0=(math.pi, 0.0, 0.0, 0.0))
    ctrl = Controller.from_rig(rig)
    ctrl.reset(0.0)
    commands = CommandPath(sim, rig.control.command_delay_ticks)
    p = model.plant.p
    kick = push or 2.0 * math.sqrt(p.epsilon / p.alpha)
    n = round(duration * rig.control.rate_hz)
    push_tick = None if push_at is None else round(push_at * rig.control.rate_hz)
    cols = {k: np.empty(n) for k in ("t", "theta", "phi", "u", "swinging")}
    true_state = np.empty((n, 4))
    first = recatch = math.nan
    falls = 0
    prev = True
    for k in range(n):
        if k == push_tick:
            sim.theta_dot += kick
        true_state[k] = sim.state
        m = sim.measure()
        out = ctrl.update(m)
        if prev and not out.swinging:
            if math.isnan(first):
                first = m.t
            elif push_tick is not None and k > push_tick and math.isnan(recatch):
                recatch = m.t - push_tick / rig.control.rate_hz
        elif out.swinging and not prev:
            falls += 1
        prev = out.swinging
        for col, value in zip(cols.values(), (m.t, m.theta, m.phi, out.u, out.swinging), strict=True):
            col[k] = value
        commands.send_and_advance(out.u)
    theta = (cols["theta"] + math.pi) % (2 * math.pi) - math.pi
    return SwingUpRun(first, recatch, falls, float(np.max(np.abs(cols["phi"]))), float(np.max(np.abs(cols["u"]))),
                      cols["t"], theta, cols["phi"], cols["u"], cols["swinging"].astype(bool), true_state)
