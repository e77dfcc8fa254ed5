"""The controller's real-time step, shared by the daemon, hil_mock runs, replay and the simulator.

One call of ``Controller.update`` per tick (read → **update** → write):

    φ̂̇ ← observer corrected with φ
    u_lin = L·[θ_f, θ̇_f, φ, φ̂̇]                       (eq. 5)
    F̂   = compensation(φ̂̇, u_lin)                     (section 7)
    u    = sat(u_lin + F̂)
    observer predicted with the net torque u − F̂ that reaches the arm after the command delay

Everything is scalar Python on floats: no allocation, no numpy on the hot path.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from furuta_rt.config import CompMode, RigConfig
from furuta_rt.control.compensation import Compensator
from furuta_rt.control.design import (
    actuated_linearization,
    lqr_gains,
    place_gains,
    pole_placement_gains,
    target_poles,
)
from furuta_rt.control.observer import ArmObserver, ArmObserverDesign
from furuta_rt.model.plant import FurutaPlant
from furuta_rt.model.sensors import Measurement


@dataclass(slots=True)
class ControlOutput:
    u: float
    u_lin: float
    u_comp: float
    phi_dot_hat: float
    saturated: bool


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
    ) -> None:
        """``command_per_torque`` converts the compensator's torque (N m) into command units
        (1 for a torque actuator, R/Kt volts per N m for a DC motor)."""
        self.command_per_torque = command_per_torque
        self.l1, self.l2, self.l3, self.l4 = (float(v) for v in gains)
        self.observer = observer
        self.compensator = compensator
        self.u_limit = u_limit
        self._pending: deque[float] = deque([0.0] * command_delay_ticks)
        self._delay = command_delay_ticks
        self._started = False

    @classmethod
    def from_rig(
        cls, rig: RigConfig, mode: CompMode | None = None, gains: np.ndarray | list[float] | None = None
    ) -> Controller:
        h = 1.0 / rig.control.rate_hz
        return cls(
            gains=design_gains(rig) if gains is None else gains,
            observer=ArmObserver(observer_design(rig)),
            compensator=Compensator.from_config(rig.compensation, h, mode),
            u_limit=rig.actuator.limit,
            command_delay_ticks=rig.control.command_delay_ticks,
            command_per_torque=1.0 if rig.actuator.kind == "torque" else rig.actuator.R / rig.actuator.Kt,  # type: ignore[operator]
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

    def update(self, m: Measurement) -> ControlOutput:
        if not self._started:
            self.reset(m.phi)
        obs = self.observer
        phi_dot = obs.correct(m.phi)
        u_lin = self.l1 * m.theta + self.l2 * m.theta_dot + self.l3 * m.phi + self.l4 * phi_dot
        u_comp = self.compensator(phi_dot, u_lin / self.command_per_torque) * self.command_per_torque
        u = u_lin + u_comp
        lim = self.u_limit
        saturated = False
        if lim is not None and (u > lim or u < -lim):
            u = lim if u > 0 else -lim
            saturated = True
        # The torque acting over the next period is the command issued `delay` ticks ago.
        if self._delay:
            self._pending.append(u - u_comp)
            applied = self._pending.popleft()
        else:
            applied = u - u_comp
        obs.predict(m.theta, applied)
        return ControlOutput(u=u, u_lin=u_lin, u_comp=u_comp, phi_dot_hat=phi_dot, saturated=saturated)

    def hold(self, m: Measurement) -> float:
        """Track the measurement without commanding (idle/tripped): keeps the observer converged.
        Returns the observer's φ̇ estimate (as ``update``'s ``phi_dot_hat``)."""
        if not self._started:
            self.reset(m.phi)
        phi_dot = self.observer.correct(m.phi)
        if self._delay:
            self._pending.append(0.0)
            applied = self._pending.popleft()
        else:
            applied = 0.0
        self.observer.predict(m.theta, applied)
        return phi_dot
