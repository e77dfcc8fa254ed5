"""Simple real-rig experiments, simulated with a seed: free swings (zero command, the arm held) and open-loop pulses
and sines on a voltage-driven arm with dry friction or a dead band, at the low rates and short lengths hobby and
teaching rigs log. Each case says what a right diagnosis names and what would be a false alarm.

In-sample: the QUBE-Servo 2 shape at the sizes, rates and seeds the tests use (the stages' thresholds were chosen
on them). Held out: the macstepien shape, other seeds, rates, amplitudes and sizes, never looked at while tuning.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from furuta_rt.config import RigConfig, load_rig
from furuta_rt.model.effects import effects_from_assignments
from furuta_rt.model.rig import RigModel
from furuta_rt.recording import Recording
from furuta_rt.sim.compiled import fast_simulator

HELD_ARM = "arm_coulomb.Fc=0.5"  # a dry friction far above the pendulum's reaction: the arm stays put


def swing_recording(rig: RigConfig, effects: list[str], rate: float, amplitude: float = 0.4, seconds: float = 20.0,
                    seed: int = 0) -> Recording:
    """The pendulum released ``amplitude`` rad from hanging, zero command, sampled at ``rate`` Hz through the rig's
    own sensors."""
    sim = fast_simulator(RigModel.from_config(rig, effects_from_assignments(effects)), rate, 5000.0, seed=seed,
                    x0=(math.pi - amplitude, 0.0, 0.0, 0.0))
    n = round(seconds * rate)
    cols = np.empty((n, 4))
    for k in range(n):
        m = sim.measure()
        cols[k] = (sim.t, m.theta, m.theta_dot, m.phi)
        sim.advance()
    return Recording(t=cols[:, 0], theta=cols[:, 1], theta_dot=cols[:, 2], phi=cols[:, 3], u=np.zeros(n))


def driven_recording(rig: RigConfig, effects: list[str], rate: float, seconds: float, command: Callable[[float], float],
                     seed: int = 0) -> Recording:
    """The rig from hanging at rest under the open-loop ``command(t)`` (volts), sampled at ``rate`` Hz; the command
    logged at a tick acts from the next one (the config's command_delay_ticks = 1)."""
    assert rig.control.command_delay_ticks == 1
    sim = fast_simulator(RigModel.from_config(rig, effects_from_assignments(effects)), rate, 5000.0, seed=seed,
                    x0=(math.pi, 0.0, 0.0, 0.0))
    n = round(seconds * rate)
    cols = np.empty((n, 5))
    for k in range(n):
        m = sim.measure()
        u = command(sim.t)
        cols[k] = (sim.t, m.theta, m.theta_dot, m.phi, u)
        sim.advance()
        sim.set_command(u)
    return Recording(t=cols[:, 0], theta=cols[:, 1], theta_dot=cols[:, 2], phi=cols[:, 3], u=cols[:, 4])


def square_pulses(volts: float) -> Callable[[float], float]:
    """+V for 0.5 s, 0 V for 1 s, −V for 0.5 s, 0 V for 1 s (a home-built rig's open-loop test)."""
    def command(t: float) -> float:
        phase = t % 3.0
        return volts if phase < 0.5 else -volts if 1.5 <= phase < 2.0 else 0.0
    return command


def slow_sine(volts: float, w: float = 1.0) -> Callable[[float], float]:
    return lambda t: volts * math.sin(w * t)


@dataclass(frozen=True)
class RealRigCase:
    name: str
    kind: str  # "swing" | "pulses" | "sine"
    shape: str  # the shipped rig the recording is made from and diagnosed against
    effects: tuple[str, ...]
    rate: float
    seconds: float
    held_out: bool
    seed: int = 0
    volts: float = 3.0
    amplitude: float = 0.4
    inertia: float = 1.0  # the true pendulum inertia about its centre, × the config's
    # what a right diagnosis says: the loss law ("viscous" | "coulomb" | "both" | None: no loss to name), a period
    # mismatch or not, the arm's rests ("dry friction" | "look-alike" | None: no claim)
    law: str | None = None
    period_mismatch: bool = False
    rests: str | None = None

    def true_rig(self) -> RigConfig:
        rig = load_rig(self.shape)
        if self.inertia == 1.0:
            return rig
        return rig.model_copy(update={"plant": rig.plant.model_copy(update={"J2": self.inertia * rig.plant.J2})})

    def generate(self) -> Recording:
        rig = self.true_rig()
        if self.kind == "swing":
            return swing_recording(rig, [*self.effects, HELD_ARM], self.rate, self.amplitude, self.seconds, self.seed)
        command = square_pulses(self.volts) if self.kind == "pulses" else slow_sine(self.volts)
        return driven_recording(rig, list(self.effects), self.rate, self.seconds, command, self.seed)

    def value(self, name: str) -> float:
        for e in self.effects:
            key, _, v = e.partition("=")
            if key == name:
                return float(v)
        return 0.0


def _swing(name: str, shape: str, effects: tuple[str, ...], law: str | None, held_out: bool, **kw) -> RealRigCase:
    return RealRigCase(name, "swing", shape, effects, kw.pop("rate", 100.0), kw.pop("seconds", 20.0), held_out,
                       law=law, **kw)


CASES: tuple[RealRigCase, ...] = (
    # in-sample: the tests' cases
    _swing("qube swing viscous", "qube_servo2", ("pendulum_viscous.bp=5e-5",), "viscous", False),
    _swing("qube swing coulomb", "qube_servo2", ("pendulum_coulomb.Fc=2e-4",), "coulomb", False),
    _swing("qube swing both", "qube_servo2", ("pendulum_viscous.bp=5e-5", "pendulum_coulomb.Fc=1e-4"), "both", False),
    _swing("qube swing J2 +30 %", "qube_servo2", ("pendulum_viscous.bp=3e-5",), "viscous", False, seed=4, inertia=1.3,
           period_mismatch=True),
    RealRigCase("qube pulses stiction 50 Hz", "pulses", "qube_servo2", ("arm_stiction.Fs=0.012", "arm_coulomb.Fc=0.008"),
                50.0, 6.0, False, rests="dry friction"),
    RealRigCase("qube pulses dead band 50 Hz", "pulses", "qube_servo2", ("input_deadzone.width=1.0", "arm_viscous.Fv=2e-4"),
                50.0, 6.0, False),
    RealRigCase("qube sine dead band", "sine", "qube_servo2", ("input_deadzone.width=1.0",), 50.0, 8.0, False, volts=1.5,
                rests="look-alike"),
    RealRigCase("qube sine stiction", "sine", "qube_servo2", ("arm_stiction.Fs=0.006", "arm_coulomb.Fc=0.004"), 50.0, 8.0,
                False, volts=1.5, rests="look-alike"),
    _swing("qube swing frictionless", "qube_servo2", (), None, False, seed=16, seconds=10.0),
    RealRigCase("qube pulses stiction 100 Hz", "pulses", "qube_servo2", ("arm_stiction.Fs=0.015", "arm_coulomb.Fc=0.01"),
                100.0, 5.0, False, seed=18, volts=4.0, rests="dry friction"),
    _swing("qube swing viscous 50 Hz, from 1 rad", "qube_servo2", ("pendulum_viscous.bp=8e-5",), "viscous", False,
           rate=50.0, seed=25, amplitude=1.0),
    # held out: other rig, seeds, rates, amplitudes and sizes
    _swing("macstepien swing viscous 200 Hz", "macstepien", ("pendulum_viscous.bp=2e-5",), "viscous", True, rate=200.0,
           seed=11, amplitude=0.8),
    _swing("macstepien swing coulomb 50 Hz", "macstepien", ("pendulum_coulomb.Fc=4e-5",), "coulomb", True, rate=50.0,
           seed=12, amplitude=0.6),
    _swing("macstepien swing both 80 Hz", "macstepien", ("pendulum_viscous.bp=1.3e-5", "pendulum_coulomb.Fc=3.8e-5"),
           "both", True, rate=80.0, seed=13, amplitude=1.2, seconds=30.0),
    _swing("macstepien swing J2 -20 %", "macstepien", ("pendulum_viscous.bp=2e-5",), "viscous", True, seed=14,
           inertia=0.8, period_mismatch=True),
    _swing("qube swing both 60 Hz, small", "qube_servo2", ("pendulum_viscous.bp=3e-5", "pendulum_coulomb.Fc=6e-5"),
           "both", True, rate=60.0, seed=15, amplitude=0.25, seconds=15.0),
    RealRigCase("macstepien pulses stiction 50 Hz", "pulses", "macstepien", ("arm_stiction.Fs=0.008", "arm_coulomb.Fc=0.005"),
                50.0, 8.0, True, seed=17, volts=1.5, rests="dry friction"),
    RealRigCase("macstepien pulses dead band", "pulses", "macstepien", ("input_deadzone.width=0.8", "arm_viscous.Fv=1e-3"),
                50.0, 8.0, True, seed=19),
    RealRigCase("qube pulses nothing 80 Hz", "pulses", "qube_servo2", (), 80.0, 5.0, True, seed=20, volts=2.0),
    RealRigCase("macstepien sine stiction", "sine", "macstepien", ("arm_stiction.Fs=0.005", "arm_coulomb.Fc=0.003"), 100.0,
                8.0, True, seed=21, volts=1.0, rests="look-alike"),
    _swing("macstepien swing frictionless 50 Hz", "macstepien", (), None, True, rate=50.0, seed=22, amplitude=0.5,
           seconds=12.0),
    RealRigCase("qube pulses stiction 80 Hz", "pulses", "qube_servo2", ("arm_stiction.Fs=0.01", "arm_coulomb.Fc=0.006"),
                80.0, 7.0, True, seed=23, rests="dry friction"),
    RealRigCase("macstepien pulses stiction 100 Hz", "pulses", "macstepien", ("arm_stiction.Fs=0.006", "arm_coulomb.Fc=0.004"),
                100.0, 7.0, True, seed=24, volts=1.2, rests="dry friction"),
    RealRigCase("macstepien sine dead band", "sine", "macstepien", ("input_deadzone.width=0.6",), 100.0, 8.0, True, seed=26,
                volts=1.0, rests="look-alike"),
    _swing("macstepien swing viscous from 1.5 rad", "macstepien", ("pendulum_viscous.bp=3e-5",), "viscous", True, seed=27,
           amplitude=1.5),
)
