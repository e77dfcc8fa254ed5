"""The controller's real-time step, shared by the daemon, hil_mock runs, replay and the simulator.

One call of ``Controller.update`` per tick (read → **update** → write):

    φ̂̇ ← observer corrected with φ
    (adaptive compensation only) F̂c learns from the observer's correction (compensation.AdaptiveCoulomb)
    u_lin = L·[θ_f, θ̇_f, φ, φ̂̇]                       (eq. 5)
    F̂   = compensation(φ̂̇, u_lin)                     (section 7)
    u    = sat(u_lin + F̂)
    observer predicted with the net torque u − F̂ that reaches the arm after the command delay

With a swing-up (``rig.swing_up.enabled``, furuta_rt.controller.swingup) the same ``update`` starts in
swinging-up mode: the energy pump replaces u_lin until the catch region, balancing takes over there (the observer
has tracked throughout, its φ set from the measurement; the compensator runs on), and a fall hands back. The
observer then sees the gravity coupling at θ as sin θ cos θ (θ near upright, exact at hanging).

With a designed experiment (``excitation``, furuta_rt.experiment.plan) the same ``update`` balances about the
plan's arm reference and adds its torque to u_lin: u_lin = L·[θ, θ̇, φ − φ_r − φ_e, φ̂̇ − φ̇_r − φ̇_e] + u_e.
A hanging plan (``excitation.open_loop``) has no feedback: u = sat(u_e), the observer tracking φ̂̇ with the gravity
coupling sin θ cos θ (exact about hanging, as with a swing-up).

Everything is scalar Python on floats: no allocation, no numpy on the hot path (the swing-up's energy aside).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import NamedTuple, Protocol

import numpy as np

from furuta_rt.config import CompMode, RigConfig
from furuta_rt.controller.compensation import Compensator
from furuta_rt.controller.design import (
    actuated_linearization,
    lqr_gains,
    place_gains,
    pole_placement_gains,
    target_poles,
)
from furuta_rt.controller.observer import ArmObserver, ArmObserverDesign
from furuta_rt.controller.swingup import SwingUp, SwingUpDesign, wrap_angle
from furuta_rt.model.plant import FurutaPlant
from furuta_rt.model.sensors import Measurement


class Excitation(Protocol):
    """A designed experiment as the controller and the run loop see it (furuta_rt.experiment.plan.Excitation builds
    one from a plan): ``step`` once per balancing tick gives (φ_e, φ̇_e, u_e); ``take_message`` a segment's start to
    log, ``done`` once the plan has returned to 0."""

    done: bool

    def step(self) -> tuple[float, float, float]: ...

    def take_message(self) -> str | None: ...


class ControlOutput(NamedTuple):
    """One tick's output of ``Controller.update`` (a named tuple: made in one C call, every tick)."""

    u: float
    u_lin: float
    u_comp: float
    phi_dot_hat: float
    saturated: bool
    swinging: bool = False  # the command came from the swing-up (not from balancing)


_new_output = tuple.__new__  # ControlOutput without its Python-level __new__ (all six fields given)


def design_gains(rig: RigConfig) -> np.ndarray:
    """L for the rig's configured design (eq. 7 pole placement, LQR or explicit gains)."""
    c = rig.control
    if c.design == "gains":
        return np.asarray(c.gains, dtype=float)
    plant = FurutaPlant(rig.lumped())
    if c.design == "lqr":
        return lqr_gains(plant, c.lqr.Q, c.lqr.R, rig.actuator)
    pp = c.pole_placement
    if rig.actuator.kind == "torque":
        return pole_placement_gains(rig.lumped(), pp.omega1, pp.omega2, pp.zeta1, pp.zeta2)
    return place_gains(plant, target_poles(pp.omega1, pp.omega2, pp.zeta1, pp.zeta2), rig.actuator)


def observer_design(rig: RigConfig) -> ArmObserverDesign:
    h = 1.0 / rig.control.rate_hz
    phi_noise = rig.observer.phi_noise or (2 * np.pi / rig.sensors.encoder_counts_per_rev) / np.sqrt(12.0)
    A, B = actuated_linearization(FurutaPlant(rig.lumped()), rig.actuator)
    return ArmObserverDesign.design(A, B, h, rig.observer.accel_noise, phi_noise)


@dataclass(frozen=True)
class ControllerDesign:
    """What ``Controller.from_rig`` computes with scipy (and python-control): the gains L and the observer's
    matrices. Plain arrays, so the daemon has them made in a helper process (``design_in_helper``) and the
    real-time process never imports scipy."""

    gains: np.ndarray
    observer: ArmObserverDesign


def controller_design(rig: RigConfig, gains: np.ndarray | list[float] | None = None) -> ControllerDesign:
    """L (``gains`` if given, else the rig's design) and the observer design for ``rig``."""
    return ControllerDesign(design_gains(rig) if gains is None else np.asarray(gains, dtype=float), observer_design(rig))


class Controller:
    """u = L·x + F̂ with a φ̇ observer; deterministic given its inputs."""

    def __init__(
        self,
        gains: np.ndarray | list[float],
        observer: ArmObserver,
        compensator: Compensator,
        u_limit: float | None,
        command_delay_ticks: int = 1,
        command_per_torque: float = 1.0,
        swing_up: SwingUp | None = None,
    ) -> None:
        """``command_per_torque`` converts the compensator's torque (N m) into command units
        (1 for a torque actuator, R/Kt volts per N m for a DC motor)."""
        self.command_per_torque = command_per_torque
        self.l1, self.l2, self.l3, self.l4 = (float(v) for v in gains)
        self.observer = observer
        self.compensator = compensator
        self._compensate = compensator.__call__  # bound once: calling the instance goes through its type every tick
        self._no_compensation = compensator.law is None
        self.u_limit = u_limit
        self._pending: deque[float] = deque([0.0] * command_delay_ticks)
        self._delay = command_delay_ticks
        self._started = False
        self.swing_up = swing_up
        self.swinging = swing_up is not None
        # after a catch: the arm's reference (φ_r, φ̇_r) starts where the arm was caught, at its speed, and returns
        # to 0 critically damped (ω = 1/arm_return_s): balancing does not fight the arm's position or momentum
        self.phi_ref = 0.0
        self.phi_dot_ref = 0.0
        self._ref_w = 0.0
        self._ref_h = 0.0
        if swing_up is not None:
            d = swing_up.design
            self._ref_w = 1.0 / d.arm_return_s
            self._ref_h = d.period
        # a designed experiment (furuta_rt.experiment.plan.Excitation): stepped once per balancing tick, it moves the
        # arm reference by (φ_e, φ̇_e) and adds u_e to the command
        self.excitation: Excitation | None = None
        od = observer.design  # arm torque (N m) per rad of innovation: velocity correction / speed per N m per tick
        self._torque_per_innovation = float(od.K[1] / od.Bd[1, 1]) / command_per_torque

    @classmethod
    def from_rig(
        cls, rig: RigConfig, mode: CompMode | None = None, gains: np.ndarray | list[float] | None = None,
        design: ControllerDesign | None = None,
    ) -> Controller:
        """The controller for ``rig``; ``design``: its gains and observer already made (``controller_design``),
        else they are made here."""
        h = 1.0 / rig.control.rate_hz
        if design is None:
            design = ControllerDesign(design_gains(rig) if gains is None else gains, observer_design(rig))  # type: ignore[arg-type]
        return cls(
            gains=design.gains,
            observer=ArmObserver(design.observer),
            compensator=Compensator.from_config(rig.compensation, h, mode),
            u_limit=rig.actuator.limit,
            command_delay_ticks=rig.control.command_delay_ticks,
            command_per_torque=1.0 if rig.actuator.kind == "torque" else rig.actuator.R / rig.actuator.Kt,  # type: ignore[operator]
            swing_up=SwingUp(SwingUpDesign.from_rig(rig)) if rig.swing_up.enabled else None,
        )

    @property
    def gains(self) -> tuple[float, float, float, float]:
        return self.l1, self.l2, self.l3, self.l4

    @property
    def pending_torques(self) -> tuple[float, ...]:
        """Net torques issued but not yet acting on the arm (the observer's input pipeline), oldest first."""
        return tuple(self._pending)

    def set_pending_torques(self, torques: list[float] | tuple[float, ...]) -> None:
        if len(torques) != len(self._pending):
            raise ValueError(f"the command pipeline holds {len(self._pending)} torques, got {len(torques)}")
        for i, value in enumerate(torques):
            self._pending[i] = float(value)

    def reset(self, phi: float = 0.0) -> None:
        """Forget history (used when arming and after a device reset)."""
        self.observer.reset(phi, 0.0)
        self.compensator.reset()
        for i in range(len(self._pending)):
            self._pending[i] = 0.0
        self._started = True
        self.phi_ref = self.phi_dot_ref = 0.0
        if self.swing_up is not None:
            self.swing_up.reset()
            self.swinging = True

    def _observer_theta(self, theta: float) -> float:
        """θ as the observer's gravity coupling sees it: θ balancing, sin θ cos θ with a swing-up or a hanging
        experiment (eq. 4's term)."""
        exc = self.excitation
        if self.swing_up is None and (exc is None or not exc.open_loop):
            return theta
        return math.sin(theta) * math.cos(theta)

    def _open_loop(self, m: Measurement, exc: Excitation) -> ControlOutput:
        """A hanging experiment's tick: the plan's torque, saturated at the actuator limit, no feedback."""
        phi_dot = self.observer.correct(m.phi)
        u = exc.step()[2]
        lim = self.u_limit
        saturated = lim is not None and (u > lim or u < -lim)
        if saturated:
            u = lim if u > 0 else -lim  # type: ignore[operator]
        self.observer.predict(math.sin(m.theta) * math.cos(m.theta), self._acting(u))
        return _new_output(ControlOutput, (u, u, 0.0, phi_dot, saturated, False))

    def update(self, m: Measurement) -> ControlOutput:
        if not self._started:
            self.reset(m.phi)
        if self.excitation is not None and self.excitation.open_loop:
            return self._open_loop(m, self.excitation)
        obs = self.observer
        su = self.swing_up
        if su is not None:
            if not -math.pi <= m.theta < math.pi:  # an encoder θ counts turns; the laws want upright at 0
                m = Measurement(m.t, wrap_angle(m.theta), m.theta_dot, m.phi)
            if self.swinging and su.catchable(m.theta, m.theta_dot):
                self.swinging = False
                obs.reset(m.phi, obs.phi_dot)  # bumpless: φ from the measurement, φ̂̇ as tracked
                self.phi_ref, self.phi_dot_ref = m.phi, obs.phi_dot  # the arm is taken back to 0 from where it was
            elif not self.swinging and su.fallen(m.theta):
                self.swinging = True
                su.reset()
        theta, phi = m.theta, m.phi
        compensator = self.compensator
        adaptive = compensator.adaptive
        if adaptive is not None and not self.swinging:  # prior φ̂̇ as regressor: independent of this tick's noise
            innovation = phi - obs.phi
            phi_dot_prior = obs.phi_dot
            phi_dot = obs.correct(phi)
            adaptive.adapt(innovation * self._torque_per_innovation, phi_dot_prior, phi)
        else:
            phi_dot = obs.correct(phi)
        if self.swinging:
            u_lin = su.command(theta, m.theta_dot, phi, phi_dot)  # type: ignore[union-attr]
        else:
            ref, ref_dot = self.phi_ref, self.phi_dot_ref
            exc = self.excitation
            if exc is None:
                u_lin = self.l1 * theta + self.l2 * m.theta_dot + self.l3 * (phi - ref) + self.l4 * (phi_dot - ref_dot)
            else:
                e_ref, e_dot, u_exc = exc.step()
                u_lin = (self.l1 * theta + self.l2 * m.theta_dot + self.l3 * (phi - ref - e_ref)
                         + self.l4 * (phi_dot - ref_dot - e_dot) + u_exc)
            if ref != 0.0 or ref_dot != 0.0:
                w, h = self._ref_w, self._ref_h
                ref_dot -= h * w * (w * ref + 2.0 * ref_dot)
                self.phi_ref, self.phi_dot_ref = ref + h * ref_dot, ref_dot
        if self._no_compensation:  # mode "none": F̂ = 0
            u_comp = 0.0
        else:
            cpt = self.command_per_torque
            u_comp = self._compensate(phi_dot, u_lin / cpt) * cpt
        u = u_lin + u_comp
        lim = self.u_limit
        saturated = False
        if lim is not None and (u > lim or u < -lim):
            u = lim if u > 0 else -lim
            saturated = True
        obs.predict(theta if su is None else self._observer_theta(theta), self._acting(u - u_comp))
        return _new_output(ControlOutput, (u, u_lin, u_comp, phi_dot, saturated, self.swinging))

    def hold(self, m: Measurement) -> float:
        """Track the measurement without commanding (idle/tripped): keeps the observer converged.
        Returns the observer's φ̇ estimate (as ``update``'s ``phi_dot_hat``)."""
        if not self._started:
            self.reset(m.phi)
        phi_dot = self.observer.correct(m.phi)
        self.observer.predict(self._observer_theta(m.theta), self._acting(0.0))
        return phi_dot

    def _acting(self, issued: float) -> float:
        """The torque acting over the next period: the command issued ``delay`` ticks ago (``issued`` joins the
        delay line), what the observer's prediction must use."""
        if not self._delay:
            return issued
        pending = self._pending
        pending.append(issued)
        return pending.popleft()
