"""Realistic recordings for the `diagnose` benchmark: voltage-driven DC-motor rigs shaped like
the QUBE-Servo 2 and the macstepien rig, recorded as real rigs record.

A case names the TRUE rig as effects on top of a shipped nominal rig (torque per volt off by ``input_gain``, the
arm's inertia off by ``arm_inertia``, arm damping, a cable spring with Coulomb friction, a constant arm torque,
pendulum damping) and a true command latency in ticks (``command_latency``, total from the sample instant; the
shipped rigs' config says 1 tick). It is driven the way such rigs are driven:

* ``sine`` / ``chirp`` / ``step`` / ``single_step``: open-loop voltage with the pendulum hanging (a sine or a
  0.2→4 Hz chirp around the arm's rest, a train of ± steps that spins the arm, one step from rest held to the end);
* ``swingup``: an energy-pumping swing-up (Åström & Furuta 2000: u ∝ (E − E_up)·sgn(θ̇ cos θ)) that hands over to
  a state feedback near upright and balances to the end (re-pumping if the pendulum falls);
* ``balance``: state-feedback balancing from near upright with a slow two-sine arm reference.

The feedback drivers are tuned on the TRUE rig (as a user's working controller is: tuned on the hardware) and see
what the recording sees. θ and φ are encoder readings (quantised to the encoder's counts, θ continuous through
±π, no analog path); the recording has no θ̇ column. The diagnosis is then run against the NOMINAL rig config, as a
user with a datasheet would.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from furuta_rt.config import RigConfig
from furuta_rt.controller.controller import design_gains
from furuta_rt.model.effects import Effects
from furuta_rt.model.rig import RigModel
from furuta_rt.model.sensors import quantise
from furuta_rt.recording import Recording
from furuta_rt.sim.command_path import CommandPath
from furuta_rt.sim.compiled import fast_simulator

# The encoder each rig shape reads θ with (rad per count) and the noise of its reading (rad): the QUBE's 2048-count
# quadrature encoder; the macstepien rig's ODrive estimate (not on a count grid in its recordings: fine steps + noise).
THETA_QUANTUM = {"qube_servo2": 2 * math.pi / 2048, "macstepien": 2 * math.pi / 8192}
THETA_NOISE = {"qube_servo2": 0.0, "macstepien": 5e-5}
SUBSTEP_HZ = 5000.0
PUMP_ACCEL = 150.0  # rad/s², the swing-up's arm acceleration far from upright


def design_rig(nominal: RigConfig, effects: Effects) -> RigConfig:
    """The nominal config with the true torque per volt and arm inertia: what a controller tuned on the hardware
    effectively knows (only used to design the data-generating feedback)."""
    g = effects.input_gain.gain if effects.input_gain else 1.0
    a = nominal.actuator
    actuator = a.model_copy(update={"Kt": a.Kt * g, "Ke": a.Ke / g}) if a.kind == "dc_motor" else a  # type: ignore[operator]
    plant = nominal.plant
    if effects.arm_inertia is not None:
        dJ = effects.arm_inertia.J - plant.arm_inertia
        field = {"general": "J1", "thesis": "J"}[plant.parametrisation]
        plant = plant.model_copy(update={field: getattr(plant, field) + dJ})
    return nominal.model_copy(update={"actuator": actuator, "plant": plant})


def true_steady_speed_per_volt(nominal: RigConfig, effects: Effects) -> float:
    """rad/s per V of the arm spinning steadily (torque per volt over the total viscous damping)."""
    a = nominal.actuator
    g = effects.input_gain.gain if effects.input_gain else 1.0
    fv = effects.arm_viscous.Fv if effects.arm_viscous else 0.0
    return g * a.Kt / a.R / (a.Kt * a.Ke / a.R + fv)  # type: ignore[operator]


def open_loop_voltage(kind: str, n: int, rate_hz: float, volts: float, seed: int) -> np.ndarray:
    """Open-loop excitation: ``sine`` (two sines), ``chirp`` (0.2→4 Hz), ``step`` (± steps, 2 s on, 1 s off) or
    ``single_step`` (1 s at rest, then one step held to the end, as the macstepien recordings)."""
    t = np.arange(n) / rate_hz
    rng = np.random.default_rng(seed)
    if kind == "sine":
        f1, f2 = 0.4 + 0.3 * rng.random(), 1.3 + 0.8 * rng.random()
        return volts * (0.7 * np.sin(2 * np.pi * f1 * t) + 0.3 * np.sin(2 * np.pi * f2 * t + 1.0))
    if kind == "chirp":
        f0, f1 = 0.2, 4.0
        T = t[-1] if n > 1 else 1.0
        phase = 2 * np.pi * (f0 * t + (f1 - f0) * t**2 / (2 * T))
        return volts * np.sin(phase)
    if kind == "step":
        period = 3.0
        k = np.floor(t / period).astype(int)
        signs = np.where(rng.random(k.max() + 1) < 0.5, -1.0, 1.0)
        levels = volts * (0.6 + 0.4 * rng.random(k.max() + 1)) * signs
        on = (t - k * period) < 2.0
        u = np.where(on, levels[k], 0.0)
        u[t < 0.5] = 0.0  # starts at rest
        return u
    if kind == "single_step":  # as the macstepien recordings: at rest, then one step held to the end
        return np.where(t >= 1.0, volts, 0.0)
    raise ValueError(f"unknown open-loop excitation {kind!r}")


def _wrap(x: float) -> float:
    return (x + math.pi) % (2 * math.pi) - math.pi


@dataclass
class _Estimator:
    """What the drivers feed back: encoder θ, φ and their filtered differences (a real rig's velocity estimate)."""

    dt: float
    cutoff_hz: float = 40.0
    th: float = math.nan
    ph: float = math.nan
    thd: float = 0.0
    phd: float = 0.0

    def update(self, th: float, ph: float) -> tuple[float, float, float, float]:
        a = 1.0 - math.exp(-2 * math.pi * self.cutoff_hz * self.dt)
        if not math.isnan(self.th):
            self.thd += a * ((th - self.th) / self.dt - self.thd)
            self.phd += a * ((ph - self.ph) / self.dt - self.phd)
        self.th, self.ph = th, ph
        return th, self.thd, ph, self.phd


def simulate(
    nominal: RigConfig,
    shape: str,
    effects: Effects,
    excitation: str,
    duration: float,
    seed: int,
    volts: float | None = None,
) -> Recording:
    """One realistic recording of the true rig (``effects`` on ``nominal``; the latency is ``command_latency``)."""
    model = RigModel.from_config(nominal, effects)
    rate = nominal.control.rate_hz
    dt = 1.0 / rate
    n = round(duration * rate)
    hanging = excitation in ("sine", "chirp", "step", "single_step", "swingup")
    rng = np.random.default_rng(seed)
    x0 = (math.pi + 0.02 * rng.standard_normal(), 0.0, 0.0, 0.0) if hanging else (0.04, 0.0, 0.0, 0.0)
    sim = fast_simulator(model, rate, SUBSTEP_HZ, seed=seed, x0=x0)
    commands = CommandPath(sim, nominal.control.command_delay_ticks)
    q_th, q_ph = THETA_QUANTUM[shape], 2 * math.pi / nominal.sensors.encoder_counts_per_rev
    noise = THETA_NOISE[shape]
    p = model.plant.p
    K_per_volt = true_steady_speed_per_volt(nominal, effects)
    limit = nominal.actuator.limit
    u_open = None
    if excitation in ("sine", "chirp", "step", "single_step"):
        # the experimenter picks a voltage that moves the arm well: ~3 rad/s (sine, chirp), 6–15 rad/s steps
        speed = {"step": 6.0, "single_step": 15.0}.get(excitation, 3.0)
        v = volts if volts is not None else speed / K_per_volt
        u_open = np.clip(open_loop_voltage(excitation, n, rate, min(v, limit), seed), -limit, limit)
    gains = np.asarray(design_gains(design_rig(nominal, effects)), float)
    ref = 0.4 * np.sin(2 * np.pi * np.arange(n) * dt / 5.0) + 0.2 * np.sin(2 * np.pi * np.arange(n) * dt / 1.7 + 1.0)
    est = _Estimator(dt)
    a = nominal.actuator
    torque_per_volt = (effects.input_gain.gain if effects.input_gain else 1.0) * a.Kt / a.R  # type: ignore[operator]
    fv = effects.arm_viscous.Fv if effects.arm_viscous else 0.0
    back_emf_volts = (a.Kt * a.Ke / a.R + fv) / torque_per_volt  # type: ignore[operator]  # holds a speed
    cols = {k: np.empty(n) for k in ("t", "theta", "phi", "u", "true_theta", "true_theta_dot", "true_phi",
                                     "true_phi_dot")}
    balancing = excitation == "balance"
    for k in range(n):
        th_t, thd_t, ph_t, phd_t = sim.state
        th_m = float(quantise(th_t + model.theta_offset + noise * rng.standard_normal(), q_th))
        ph_m = float(quantise(ph_t, q_ph))
        th, thd, ph, phd = est.update(th_m, ph_m)
        if u_open is not None:
            u = float(u_open[k])
        else:
            thw = _wrap(th)
            if excitation == "swingup" and not balancing and abs(thw) < 0.35 and abs(thd) < 6.0:
                balancing = True
            if excitation == "swingup" and balancing and abs(thw) > 0.6:
                balancing = False  # fell: pump again
            if balancing:
                r = ref[k] if excitation == "balance" else 0.0
                u = float(gains @ np.array([thw, thd, ph - r, phd]))
            else:
                # arm acceleration ∝ the energy missing to upright (0 there), in phase with θ̇ cos θ, plus a weak
                # centring of the arm (2 rad/s, damped)
                energy = 0.5 * p.alpha * thd**2 + p.epsilon * (math.cos(th) - 1.0)
                missing = max(-1.0, min(1.0, 5.0 * (0.05 - energy / (2.0 * p.epsilon))))
                accel = -PUMP_ACCEL * missing * math.copysign(1.0, thd * math.cos(th) if thd else 1.0)
                accel -= 1.0 * ph + 0.5 * phd
                u = p.beta * accel / torque_per_volt + back_emf_volts * phd
            u = max(-limit, min(limit, u))
        row = (sim.t, th_m, ph_m, u, th_t, thd_t, ph_t, phd_t)
        for col, value in zip(cols.values(), row, strict=True):
            col[k] = value
        commands.send_and_advance(u)
    return Recording(t=cols.pop("t"), theta=cols.pop("theta"), phi=cols.pop("phi"), u=cols.pop("u"),
                     theta_dot=None, extra=cols, meta={"rig": nominal.name, "seed": seed, "excitation": excitation})
