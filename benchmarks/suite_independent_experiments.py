"""The designed-experiment benchmark's pairs on the independent simulator (benchmarks.suite_independent): the truth
concealed in a simulator that shares nothing with ours but the thesis' physics, so the experiment `experiment design`
chose on our simulator runs under another group's plant integration, sensor path, friction law and controller.

What it adds to suite_independent's balancing simulator (its Lagrangian plant, Bessel θ path, encoder, RK4, LQR are
used as they are): the effects of the look-alike pairs written again here from their physical meaning — a torque gain,
the arm's inertia (the datasheet's J changed), viscous and smooth Coulomb arm friction, a constant torque on the arm
(bias), a cable spring −k (φ − φ0), a dead band that removes ``width`` from |u| — and the two ways an experiment runs:

* balancing: the independent LQR balances about the plan's arm reference with the plan's torque added to u (after
  ``settle_s`` of balancing at φ_r = 0), from upright at rest; the passive recording keeps the simulator's own ±0.3 rad
  square-wave reference;
* hanging: open loop from hanging at rest, ``settle_s`` at u = 0, then the plan's torque; θ read modulo 2π in
  [−π, π) as the thesis rig's full-turn sensor reads it.

Every recording here is one our design, joint fit and score never saw while they were built (held out); a case's
``held_out`` flag says whether its *pair* was tuned on in our simulator (benchmarks.suite_experiments).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from benchmarks.suite_experiments import CASES as OUR_CASES
from benchmarks.suite_experiments import PairCase
from benchmarks.suite_independent import (
    COULOMB_VS,
    COUNTS,
    RATE,
    SUBSTEPS,
    THETA_DOT_NOISE,
    THETA_NOISE,
    Lagrangian,
    Rig,
    bessel,
    lqr,
    rk4,
)
from furuta_rt.experiment.plan import Plan, reference_and_torque
from furuta_rt.recording import Recording

U_LIMIT = 2.0  # the thesis rig's actuator limit (appendix C), N m
LATENCY_TICKS = 1


@dataclass(frozen=True)
class Truth:
    """A concealed rig, in the independent simulator's own terms."""

    rig: Rig = field(default_factory=Rig)
    gain: float = 1.0
    arm_viscous: float = 0.0
    arm_coulomb: float = 0.0
    arm_bias: float = 0.0
    spring_k: float = 0.0
    spring_phi0: float = 0.0
    deadzone: float = 0.0

    @classmethod
    def from_effects(cls, effects: dict[str, dict[str, float]]) -> Truth:
        """The independent simulator's version of an effects dict (the suite's truths); KeyError for one it lacks."""
        kw: dict[str, object] = {}
        for name, p in effects.items():
            if name == "input_gain":
                kw["gain"] = p["gain"]
            elif name == "arm_inertia":
                kw["rig"] = Rig(J=p["J"])
            elif name == "arm_viscous":
                kw["arm_viscous"] = p["Fv"]
            elif name == "arm_coulomb":
                kw["arm_coulomb"] = p["Fc"]
            elif name == "arm_bias":
                kw["arm_bias"] = p["tau"]
            elif name == "arm_spring":
                kw["spring_k"], kw["spring_phi0"] = p["k"], p.get("phi0", 0.0)
            elif name == "input_deadzone":
                kw["deadzone"] = p["width"]
            else:
                raise KeyError(name)
        return cls(**kw)  # type: ignore[arg-type]

    def arm_torque(self, u: float, phi: float, phi_dot: float) -> float:
        """The torque on the arm for command u: dead band, gain, bias, spring, friction."""
        if self.deadzone:
            u = math.copysign(max(abs(u) - self.deadzone, 0.0), u)
        return (self.gain * u + self.arm_bias - self.spring_k * (phi - self.spring_phi0) - self.arm_viscous * phi_dot
                - self.arm_coulomb * math.tanh(phi_dot / COULOMB_VS))


CASES: list[PairCase] = list(OUR_CASES)
"""The same pairs and nulls as our simulator's benchmark (every truth there has an independent version here)."""


def _wrap(theta: float) -> float:
    return (theta + math.pi) % (2 * math.pi) - math.pi


def simulate(truth: Truth, duration: float, seed: int, plan: Plan | None = None) -> Recording:
    """``duration`` s balancing (``plan`` None: the passive run with the square-wave reference), or the plan: balancing
    about its reference with its torque added, or open loop from hanging for a hanging plan (``duration`` unused)."""
    hanging = plan is not None and plan.mode == "hanging"
    h = 1.0 / RATE
    if plan is None:
        n = round(duration * RATE)
        ref = ref_dot = u_exc = None
    else:
        r, rd, ue = reference_and_torque(plan, RATE, with_return=not hanging)
        settle = round(plan.settle_s * RATE)
        ref, ref_dot, u_exc = (np.concatenate([np.zeros(settle), a]) for a in (r, rd, ue))
        n = len(ref)
    plant = Lagrangian(truth.rig)
    K = lqr(Lagrangian(Rig()))  # designed on the datasheet rig
    b0, a1, a0 = bessel()

    def rhs(x: list[float], u: float) -> list[float]:
        th, thd, ph, phd, y, yd = x
        thdd, phdd = plant.accelerations(th, thd, phd, 0.0, truth.arm_torque(u, ph, phd))
        return [thd, thdd, phd, phdd, yd, b0 * th - a1 * yd - a0 * y]

    rng = np.random.default_rng(seed)
    th0 = math.pi if hanging else (0.02 if plan is None else 0.0)
    s = [th0, 0.0, 0.0, 0.0, th0, 0.0]
    pending = [0.0] * LATENCY_TICKS
    cols = {k: np.empty(n) for k in ("theta", "theta_dot", "phi", "u")}
    phi_prev, v_hat, tau_v = 0.0, 0.0, 0.01
    for k in range(n):
        t = k * h
        theta_m = s[4] + THETA_NOISE * rng.standard_normal()
        theta_dot_m = s[5] + THETA_DOT_NOISE * rng.standard_normal()
        phi_m = round(s[2] / (2 * math.pi) * COUNTS) * 2 * math.pi / COUNTS
        if k:
            v_hat += (h / (tau_v + h)) * ((phi_m - phi_prev) / h - v_hat)
        phi_prev = phi_m
        if hanging:
            u = float(u_exc[k])  # type: ignore[index]
            theta_m = _wrap(theta_m)
        else:
            if plan is None:
                r_k, rd_k, ue_k = (0.3 if (t % 4.0) < 2.0 else -0.3), 0.0, 0.0
            else:
                r_k, rd_k, ue_k = ref[k], ref_dot[k], u_exc[k]  # type: ignore[index]
            u = float(-K @ np.array([theta_m, theta_dot_m, phi_m - r_k, v_hat - rd_k]) + ue_k)
        u = min(max(u, -U_LIMIT), U_LIMIT)
        cols["theta"][k], cols["theta_dot"][k], cols["phi"][k], cols["u"][k] = theta_m, theta_dot_m, phi_m, u
        pending.append(u)
        acting = pending.pop(0)
        s = rk4(lambda x, u=acting: rhs(x, u), s, h / SUBSTEPS, SUBSTEPS)
        if not hanging and abs(s[0]) > 0.6:
            raise RuntimeError(f"the independent controller lost the pendulum at t = {t:.2f} s")
    meta = {"simulator": "independent (scipy)", "mode": "hanging" if hanging else "balancing", "seed": seed}
    return Recording(t=np.arange(n) * h, **cols, meta=meta)
