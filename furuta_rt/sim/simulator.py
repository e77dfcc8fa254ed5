"""Fixed-step simulator of the nonlinear rig (eq. 4) with friction, actuator and sensor chain.

Time is advanced in control ticks (default 500 Hz), each split into physics substeps (default
10 kHz). Each substep:

1. the shaped, delayed command gives the arm torque τ0 − d·φ̇ (d: DC-motor back-EMF), plus arm_bias;
2. the arm's dry friction is resolved *implicitly* (time-stepping à la Moreau/Stewart): the torque
   that would stop the arm within the substep is computed from the arm compliance (M⁻¹)₂₂; if it lies
   within the breakaway limit the arm sticks (φ̇ = 0 exactly, reduced dynamics for θ), otherwise it
   slides against ±Fc. No chattering at φ̇ ≈ 0, and no ε to tune;
3. LuGre's bristle state is advanced with its exact exponential solution for the substep (stable for
   any stiffness σ0), its force held over the substep;
4. the smooth dynamics (eq. 4, viscous terms, spring, pendulum friction, the torque-law effects of the registry
   (furuta_rt.model.effects.JointTorque), and the Bessel filter
   states driven by θ) are integrated with classical RK4.

Without friction or input the scheme is plain RK4 on a Hamiltonian system: energy drift over 10 s is
~1e-10 at 10 kHz. The only randomness (sensor noise) comes from a seeded generator.
"""

from __future__ import annotations

import dataclasses
import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from furuta_rt.model.friction import Coulomb, CoulombStiction, JointFriction
from furuta_rt.model.rig import RigModel
from furuta_rt.model.sensors import Calibration, Measurement


@dataclass(slots=True)
class RawSample:
    """What the DAQ reads at a tick (counts), with its own status."""

    theta_adc: int
    theta_dot_adc: int
    phi_count: int
    overrange: bool


class Simulator:
    """The rig in simulation. Call ``set_command`` then ``advance``; read with ``sample``/``measure``."""

    def __init__(
        self,
        model: RigModel,
        rate_hz: float = 500.0,
        substep_hz: float = 10_000.0,
        seed: int = 0,
        x0: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0),
    ) -> None:
        if rate_hz <= 0 or substep_hz < rate_hz:
            raise ValueError(f"need 0 < rate_hz <= substep_hz, got {rate_hz}, {substep_hz}")
        self.model = model
        self.rate_hz = rate_hz
        self.n_sub = max(1, round(substep_hz / rate_hz))
        self.h = 1.0 / (rate_hz * self.n_sub)
        self.rng = np.random.default_rng(seed)
        self.t = 0.0
        self.theta, self.theta_dot, self.phi, self.phi_dot = (float(v) for v in x0)
        self.y = self.theta + model.theta_offset  # Bessel states start settled
        self.y_dot = 0.0
        self.z = 0.0  # LuGre bristle deflection
        self._coupling = model.coupling
        self.rotor, self.rotor_dot = self.phi, self.phi_dot  # the motor's rotor (with a compliant coupling only)
        self.stuck = False
        self.arm_friction_torque = 0.0
        self.command = 0.0
        # the delay line's part of the latency rule (the driver's whole ticks are CommandPath's): the actuator's delay,
        # or a command_latency whole, the driver then setting the command at the sample instant (commands_at_sample)
        _, lag = model.command_timing(0)
        n_delay = round(lag / self.h)
        self._bias = model.arm_bias
        self._delay_line: deque[float] = deque([0.0] * n_delay)
        p = model.plant.p
        self._alpha, self._beta, self._gamma, self._eps = p.alpha, p.beta, p.gamma, p.epsilon
        self._use_arm_friction(model.arm_friction)
        pf = model.pendulum_friction
        self._bp = pf.viscous.Fv if pf.viscous else 0.0
        self._pend_dry = pf.dry
        self._k = model.spring_k
        self._phi0 = model.spring_phi0
        if model.bessel is not None:
            self._fa1, self._fa0 = model.bessel.coefficients()
        else:
            self._fa1 = self._fa0 = 0.0
        self._rhs = self._make_rhs()
        self._shaped_for = math.nan  # the command whose actuator torque terms are in _shaped
        self._shaped = (0.0, 0.0)

    # ------------------------------------------------------------------ state
    @property
    def state(self) -> tuple[float, float, float, float]:
        """True x = [θ, θ̇, φ, φ̇]."""
        return self.theta, self.theta_dot, self.phi, self.phi_dot

    def energy(self) -> float:
        return self.model.plant.energy(self.theta, self.theta_dot, self.phi_dot)

    @property
    def commands_in_flight(self) -> tuple[float, ...]:
        """The substep commands queued in the actuator's transport delay, oldest first."""
        return tuple(self._delay_line)

    def set_commands_in_flight(self, commands: list[float] | tuple[float, ...]) -> None:
        """Fill the actuator's delay line (e.g. from recorded commands when starting mid-recording)."""
        if len(commands) != len(self._delay_line):
            raise ValueError(f"the delay line holds {len(self._delay_line)} substep commands, got {len(commands)}")
        self._delay_line.clear()
        self._delay_line.extend(float(c) for c in commands)

    @property
    def commands_at_sample(self) -> bool:
        """True when the rig has a ``command_latency``: the driver sets the command answering a sample at that
        sample's instant (before ``advance``) and the delay line makes it act ``command_latency`` s later. False:
        the driver sets it one tick later (the protocol's lag), the line adding the actuator's ``input_delay``."""
        return self.model.command_timing(1)[0] == 0

    def set_command(self, command: float) -> None:
        """The actuator command (N m or V) from now on (the actuator's own delay still applies)."""
        self.command = float(command)

    def set_arm_friction(self, friction: JointFriction) -> None:
        """Change the arm's friction from now on (a worn or re-greased bearing: hil_mock's friction_step fault)."""
        self.model = dataclasses.replace(self.model, arm_friction=friction)
        self._use_arm_friction(friction)
        self._rhs = self._make_rhs()
        if friction.lugre is None:
            self.z = 0.0
        if friction.dry is None:
            self.stuck = False

    def _use_arm_friction(self, af: JointFriction) -> None:
        self._fv_arm = af.viscous.Fv if af.viscous else 0.0
        dry = af.dry
        self._fc = dry.sliding_level if isinstance(dry, Coulomb | CoulombStiction) else 0.0
        self._fs = dry.stick_limit if isinstance(dry, Coulomb | CoulombStiction) else 0.0
        self._set_valued = dry is not None and not (isinstance(dry, Coulomb) and dry.epsilon > 0)
        self._smooth_dry = dry if (dry is not None and not self._set_valued) else None
        self._lugre = af.lugre

    # ------------------------------------------------------------ dynamics
    def _make_rhs(self) -> Callable[..., tuple[float, float, float, float]]:
        """The smooth dynamics as a closure over the model's constants (the hot path: 4 calls a substep)."""
        accelerations = self.model.plant.accelerations  # eq. 4: the one definition
        fv_arm, k, phi0, bp = self._fv_arm, self._k, self._phi0, self._bp
        smooth_dry, pend_dry = self._smooth_dry, self._pend_dry
        fa0, fa1, offset = self._fa0, self._fa1, self.model.theta_offset
        joint_torque = self.model.joint_torque if self.model.joint_torques else None  # the registry's torque laws

        def rhs(
            th: float, thd: float, ph: float, phd: float, y: float, yd: float, tau0: float, damp: float, F: float
        ) -> tuple[float, float, float, float]:
            """(θ̈, φ̈, ÿ, 0): eq. 4 with the joint torques, and the Bessel filter driven by θ."""
            tau_arm = tau0 - (damp + fv_arm) * phd + F - k * (ph - phi0)
            if smooth_dry is not None:
                tau_arm += smooth_dry.torque(phd)
            tau_p = -bp * thd
            if pend_dry is not None:
                tau_p += pend_dry.torque(thd)
            if joint_torque is not None:
                extra_p, extra_a = joint_torque(th, thd, ph, phd)
                tau_p += extra_p
                tau_arm += extra_a
            thdd, phdd = accelerations(th, thd, phd, tau_arm, tau_p)
            return thdd, phdd, fa0 * (th + offset - y) - fa1 * yd, 0.0

        return rhs

    def _rhs_stuck(self, th: float, thd: float, y: float, yd: float) -> tuple[float, float]:
        """Arm held by friction (φ̇ = φ̈ = 0): α θ̈ = ε sin θ + τ_pend (first row of eq. 4)."""
        tau_p = -self._bp * thd
        if self._pend_dry is not None:
            tau_p += self._pend_dry.torque(thd)
        if self.model.joint_torques:
            tau_p += self.model.joint_torque(th, thd, self.phi, 0.0)[0]
        thdd = (self._eps * math.sin(th) + tau_p) / self._alpha
        ydd = self._fa0 * (th + self.model.theta_offset - y) - self._fa1 * yd
        return thdd, ydd

    def _held_torque(self, tau_arm_ext: float) -> float:
        """Friction torque needed to keep the arm at rest (arm row of eq. 4 with φ̇ = φ̈ = 0)."""
        th, thd = self.theta, self.theta_dot
        thdd, _ = self._rhs_stuck(th, thd, self.y, self.y_dot)
        if self.model.joint_torques:
            tau_arm_ext += self.model.joint_torque(th, thd, self.phi, 0.0)[1]
        return self.model.plant.inverse_dynamics(th, thd, 0.0, thdd, 0.0)[1] - tau_arm_ext

    def _substep(self, command: float) -> None:
        h = self.h
        if command != self._shaped_for:  # the shaped command changes at most once a tick (or per delayed substep)
            self._shaped_for = command
            self._shaped = self.model.actuator.torque_terms(command)
        tau0, damp = self._shaped
        if self._coupling is not None:  # the motor drives its rotor; the arm gets the coupling's torque
            self.rotor, self.rotor_dot, tau0 = self._coupling.advance(
                self.rotor, self.rotor_dot, tau0 - damp * self.rotor_dot, self.phi, self.phi_dot, self.h)
            damp = 0.0
        tau0 += self._bias  # arm_bias: a constant torque on the arm
        th, thd, ph, phd, y, yd = self.theta, self.theta_dot, self.phi, self.phi_dot, self.y, self.y_dot

        F = 0.0
        if self._lugre is not None:
            self.z, z_dot = self._lugre.advance(self.z, phd, h)
            F = self._lugre.torque(self.z, z_dot, phd)
        elif self._set_valued:
            spring = -self._k * (ph - self._phi0) if self._k else 0.0
            if self.stuck:
                held = self._held_torque(tau0 + spring)
                if abs(held) <= self._fs:
                    self.arm_friction_torque = held
                    self._integrate_stuck(h)
                    return
                self.stuck = False
                F = math.copysign(self._fc, held)  # slides against the net external torque
            else:
                phdd0 = self._rhs(th, thd, ph, phd, y, yd, tau0, damp, 0.0)[1]
                v_free = phd + h * phdd0
                comp = self.model.plant.arm_compliance(th)
                direction = phd if phd != 0.0 else v_free
                F = -math.copysign(self._fc, direction)
                v_slide = phd + h * (phdd0 + comp * F)
                if phd == 0.0 or v_slide * direction <= 0.0:  # at rest, or comes to rest in this substep
                    needed = -v_free / (h * comp)
                    if abs(needed) <= self._fs:
                        self.stuck = True
                        self.phi += 0.5 * h * phd
                        self.phi_dot = 0.0
                        self.arm_friction_torque = needed
                        self._integrate_stuck(h)
                        return
                    F = -math.copysign(self._fc, v_free)
        self.arm_friction_torque = F

        # Classical RK4 with F, τ0 held over the substep.
        k1 = self._rhs(th, thd, ph, phd, y, yd, tau0, damp, F)
        h2 = 0.5 * h
        k2 = self._rhs(
            th + h2 * thd, thd + h2 * k1[0], ph + h2 * phd, phd + h2 * k1[1], y + h2 * yd, yd + h2 * k1[2],
            tau0, damp, F,
        )
        thd2, phd2, yd2 = thd + h2 * k1[0], phd + h2 * k1[1], yd + h2 * k1[2]
        k3 = self._rhs(
            th + h2 * thd2, thd + h2 * k2[0], ph + h2 * phd2, phd + h2 * k2[1], y + h2 * yd2, yd + h2 * k2[2],
            tau0, damp, F,
        )
        thd3, phd3, yd3 = thd + h2 * k2[0], phd + h2 * k2[1], yd + h2 * k2[2]
        k4 = self._rhs(
            th + h * thd3, thd + h * k3[0], ph + h * phd3, phd + h * k3[1], y + h * yd3, yd + h * k3[2],
            tau0, damp, F,
        )
        thd4, phd4, yd4 = thd + h * k3[0], phd + h * k3[1], yd + h * k3[2]
        h6 = h / 6.0
        self.theta = th + h6 * (thd + 2.0 * thd2 + 2.0 * thd3 + thd4)
        self.phi = ph + h6 * (phd + 2.0 * phd2 + 2.0 * phd3 + phd4)
        self.y = y + h6 * (yd + 2.0 * yd2 + 2.0 * yd3 + yd4)
        self.theta_dot = thd + h6 * (k1[0] + 2.0 * k2[0] + 2.0 * k3[0] + k4[0])
        self.phi_dot = phd + h6 * (k1[1] + 2.0 * k2[1] + 2.0 * k3[1] + k4[1])
        self.y_dot = yd + h6 * (k1[2] + 2.0 * k2[2] + 2.0 * k3[2] + k4[2])

    def _integrate_stuck(self, h: float) -> None:
        th, thd, y, yd = self.theta, self.theta_dot, self.y, self.y_dot
        h2 = 0.5 * h
        a1, b1 = self._rhs_stuck(th, thd, y, yd)
        a2, b2 = self._rhs_stuck(th + h2 * thd, thd + h2 * a1, y + h2 * yd, yd + h2 * b1)
        a3, b3 = self._rhs_stuck(th + h2 * (thd + h2 * a1), thd + h2 * a2, y + h2 * (yd + h2 * b1), yd + h2 * b2)
        a4, b4 = self._rhs_stuck(th + h * (thd + h2 * a2), thd + h * a3, y + h * (yd + h2 * b2), yd + h * b3)
        h6 = h / 6.0
        self.theta = th + h6 * (thd + 2 * (thd + h2 * a1) + 2 * (thd + h2 * a2) + (thd + h * a3))
        self.y = y + h6 * (yd + 2 * (yd + h2 * b1) + 2 * (yd + h2 * b2) + (yd + h * b3))
        self.theta_dot = thd + h6 * (a1 + 2 * a2 + 2 * a3 + a4)
        self.y_dot = yd + h6 * (b1 + 2 * b2 + 2 * b3 + b4)
        self.phi_dot = 0.0

    def advance(self, ticks: int = 1) -> None:
        """Integrate ``ticks`` control periods with the current command."""
        line = self._delay_line
        for _ in range(ticks * self.n_sub):
            if line:
                line.append(self.command)
                cmd = line.popleft()
            else:
                cmd = self.command
            self._substep(cmd)
        self.t += ticks / self.rate_hz

    # ------------------------------------------------------------ sensing
    def filtered_theta(self) -> tuple[float, float]:
        """(θ_f, θ̇_f) at the analog path's output, before the ADC (no noise)."""
        if self.model.bessel is None:
            return self.theta + self.model.theta_offset, self.theta_dot
        return self.y, self.y_dot

    def sample(self) -> RawSample:
        """The DAQ's reading now: ADC of the analog path with noise, encoder count of φ."""
        th_f, thd_f = self.filtered_theta()
        m = self.model
        if m.theta_noise:
            th_f += m.theta_noise * self.rng.standard_normal()
        if m.theta_dot_noise:
            thd_f += m.theta_dot_noise * self.rng.standard_normal()
        a, b, c, over = m.calibration.to_counts(th_f, thd_f, self.phi)
        return RawSample(a, b, c, over)

    def measure(self, calibration: Calibration | None = None) -> Measurement:
        """``sample`` converted to SI with the calibration (what the controller sees); ``calibration``: the host's,
        when it differs from the DAQ's (a calibration error), default the rig's own."""
        s = self.sample()
        th, thd, ph = (calibration or self.model.calibration).to_si(s.theta_adc, s.theta_dot_adc, s.phi_count)
        return Measurement(self.t, th, thd, ph)
