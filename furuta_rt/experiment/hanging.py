"""Experiments with the pendulum hanging: open loop, the plan's torque on the arm, the pendulum swinging about θ = π.

Balancing keeps the pendulum within a few hundredths of a radian of upright, so the pendulum's reaction on the arm
(γ cos θ θ̈ in eq. 4's arm equation) stays a fraction of a percent of the arm torque — and that reaction is the one
term an input gain scales and an arm-inertia change does not. Hanging, a small torque near the pendulum's natural
frequency swings it through tenths of a radian: the reaction is then comparable to the arm's own inertia torque.

The free-arm natural frequency follows from eq. 6's parameters linearised about θ = π with no torque on the arm:
α θ̈ − γ φ̈ = −ε (θ − π), β φ̈ = γ θ̈, so ω² = ε / (α − γ²/β).
"""

from __future__ import annotations

import math

import numpy as np

from furuta_rt.config import RigConfig
from furuta_rt.experiment.plan import Plan, Segment, reference_and_torque
from furuta_rt.model.effects import Effects
from furuta_rt.recording import Recording

SWING_LIMIT = 1.0  # rad: the default |θ − π| a hanging plan may reach (well short of the horizontal)


def natural_frequency(rig: RigConfig) -> float:
    """The hanging pendulum's natural frequency with the arm free (Hz)."""
    from furuta_rt.model.plant import FurutaPlant

    p = FurutaPlant(rig.lumped()).p
    return math.sqrt(p.epsilon / (p.alpha - p.gamma**2 / p.beta)) / (2 * math.pi)


def candidate_plans(rig: RigConfig, budget_s: float, settle_s: float = 1.0) -> list[Plan]:
    """Chirps across the natural frequency (0.5–2×) and dithers near it, at 0.5 %, 1.5 % and 3 % of the |u| limit:
    the resonance needs little torque, and a torque that turns the arm one way for long drives it far open loop."""
    f = natural_frequency(rig)
    u_lim = rig.actuator.limit
    plans = []
    for frac in (0.005, 0.015, 0.03):
        a = frac * u_lim
        plans.append(Plan((Segment("chirp", budget_s, {"amplitude": a, "f0": round(0.5 * f, 3), "f1": round(2 * f, 3)}),),
                          mode="hanging", settle_s=settle_s))
        for k in (0.9, 1.2):
            plans.append(Plan((Segment("dither", budget_s, {"amplitude": a, "frequency": round(k * f, 3)}),),
                              mode="hanging", settle_s=settle_s))
    return plans


def simulate(rig: RigConfig, effects: dict[str, dict[str, float]], plan: Plan, seed: int, *, substep_hz: float,
             noise: bool = True) -> Recording:
    """The plan open loop from hanging at rest: ``settle_s`` at zero command, then the plan's torque (the command path
    of furuta_rt.sim.command_path: the rig's command delay), measured as the rig measures (θ modulo 2π where its
    sensor wraps); without sensor noise when not ``noise``."""
    from furuta_rt.model.rig import RigModel
    from furuta_rt.sim.command_path import CommandPath
    from furuta_rt.sim.simulator import Simulator

    if not noise:
        sensors = rig.sensors.model_copy(update={"theta_noise": 0.0, "theta_dot_noise": 0.0})
        rig = rig.model_copy(update={"sensors": sensors})
    rate = rig.control.rate_hz
    _, _, torque = reference_and_torque(plan, rate, with_return=False)
    u = np.concatenate([np.zeros(round(plan.settle_s * rate)), torque])
    sim = Simulator(RigModel.from_config(rig, Effects.model_validate(effects)), rate, substep_hz, seed=seed,
                    x0=(math.pi, 0.0, 0.0, 0.0))
    commands = CommandPath(sim, rig.control.command_delay_ticks)
    cols = np.empty((5, len(u)))
    for k, command in enumerate(u):
        m = sim.measure()
        cols[:, k] = (m.t, m.theta, m.theta_dot, m.phi, command)
        commands.send_and_advance(float(command))
    return Recording(t=cols[0], theta=cols[1], phi=cols[3], u=cols[4], theta_dot=cols[2],
                     meta={"rig": rig.name, "mode": "hanging", "seed": seed})


def swing(theta: np.ndarray) -> float:
    """The largest |θ − π| (wrapped): how far from hanging the pendulum swung."""
    return float(np.max(np.abs(np.angle(-np.exp(1j * np.asarray(theta))))))
