"""The library of candidate physics: how each named effect changes the inverse-dynamics residual.

For one equation of eq. 4 the residual of the nominal model is

    y = ID(x̂) − τ_known            (arm: τ_known = K*[applied command torque]; pendulum: 0)

and an effect adds the torque the nominal model misses (friction, spring) or changes a parameter
(inertia, θ offset, gain). Near the data, y ≈ Σ c_i X_i with columns X_i built here *from the shared
models*: friction laws of furuta_rt.model.friction, the actuator chain of furuta_rt.model.actuator
(delay, deadzone, saturation are nonlinear parameters of the command torque), and derivatives of
FurutaPlant.inverse_dynamics for parameter changes (θ offset, arm inertia). Nothing of eq. 1 or eq. 4
is re-typed here.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from furuta_rt.config import RigConfig
from furuta_rt.diagnose.regression.states import Prepared, States
from furuta_rt.model.actuator import Actuator
from furuta_rt.model.effects import ARM, EFFECT_TYPES, PEND, Effect, JointTorque, total_latency
from furuta_rt.model.friction import Coulomb, LuGre, law_on_array
from furuta_rt.model.plant import FurutaPlant
from furuta_rt.model.rig import RigModel


def piecewise_linear_on_array(f, x: np.ndarray, kinks: tuple[float, ...]) -> np.ndarray:
    """A scalar, piecewise-linear function (the actuator chain) on an array: interpolated between its
    values on a dense grid that also holds the expected kinks (exact when the kinks are among them)."""
    lo, hi = float(np.min(x)), float(np.max(x))
    nodes = np.unique(np.concatenate([np.linspace(lo, hi, 1025), [0.0], [k for k in kinks if lo < k < hi]]))
    return np.interp(x, nodes, [f(float(v)) for v in nodes])


def actuator_kinks(act: Actuator) -> tuple[float, ...]:
    """Where the command → torque map of ``act`` bends: deadzone edges and saturation onsets."""
    dz, lim = act.deadzone / act.gain, act.limit
    out = [dz, -dz]
    if lim is not None:
        out += [dz + lim / act.gain, -dz - lim / act.gain]
    return tuple(out)


@dataclass(frozen=True)
class InputPath:
    """Nonlinear parameters of the command → torque chain (furuta_rt.model.actuator.Actuator order:
    delay, gain, deadzone, saturation). ``deadzone``/``limit`` are in command units before the gain;
    the gain is linear on top: τ = g·shape(u), and shape commutes with g (dz_w(g u) = g·dz_{w/g}(u))."""

    delay: float = 0.0
    deadzone: float = 0.0
    limit: float | None = None


@dataclass
class Context:
    """Everything the columns need for one recording, computed once."""

    prep: Prepared
    rig: RigConfig
    plant: FurutaPlant
    model: RigModel
    arm: States
    pend: States
    fine: States
    also_search: frozenset[str] = frozenset()  # registered effects outside the default search to try as well
    _held: dict[InputPath, np.ndarray] = field(default_factory=dict)
    _tau0: dict[tuple[float, float | None], np.ndarray] = field(default_factory=dict)
    _columns: dict[str, np.ndarray] = field(default_factory=dict)

    @classmethod
    def build(cls, prep: Prepared, rig: RigConfig, sigma_arm: float, sigma_pend: float, sigma_fine: float,
              also_search: frozenset[str] = frozenset()) -> Context:
        model = RigModel.from_config(rig)  # the rig with its own [effects]: the nominal model includes them
        fine = prep.states(sigma_fine)
        return cls(
            prep=prep, rig=rig, plant=model.plant, model=model,
            arm=prep.states(sigma_arm, fine), pend=prep.states(sigma_pend, fine), fine=fine, also_search=also_search,
        )

    def states(self, equation: str) -> States:
        return self.arm if equation == ARM else self.pend

    # ------------------------------------------------------------------ the rig's own effects
    @property
    def known(self) -> dict[str, dict[str, float]]:
        """The rig's own [effects] (part of the nominal model; diagnose reports what is still missing, as totals)."""
        return self.rig.effects.present()

    def known_value(self, name: str, param: str, default: float = 0.0) -> float:
        return float(self.known.get(name, {}).get(param, default))

    @cached_property
    def known_gain(self) -> float:
        return self.model.actuator.gain

    @cached_property
    def base_path(self) -> InputPath:
        """The command path of the nominal model (the rig's own delay, deadzone, limit; in command units)."""
        a, g = self.model.actuator, self.known_gain
        return InputPath(delay=self.base_delay, deadzone=a.deadzone / g, limit=None if a.limit is None else a.limit / g)

    @cached_property
    def base_delay(self) -> float:
        """The nominal model's delay on top of command_delay_ticks·h: the rig's own input_delay, or its own
        command_latency (a total) less command_delay_ticks·h (negative when the command acts sooner)."""
        ticks, delay = self.model.command_timing(round(self.prep.command_lag / self.prep.dt))
        return delay - (self.prep.command_lag - ticks * self.prep.dt)

    @cached_property
    def base_inertia(self) -> float:
        """The arm inertia J of the nominal model (the rig's own arm_inertia effect, else the config's)."""
        return self.known_value("arm_inertia", "J", self.rig.plant.arm_inertia)

    def inverse_dynamics(self, equation: str, plant: FurutaPlant | None = None, theta_shift: float = 0.0,
                         phi_ddot: bool = True) -> np.ndarray:
        """K * ID of eq. 4 evaluated on the lightly smoothed states (signals.States: = C * ID of the true states at
        any amplitude), θ corrected by the rig's known sensor offset (and ``theta_shift``); without the φ̈ term
        when not ``phi_ddot``."""
        s = self.states(equation)
        b = s.base
        pl = plant or self.plant
        x = [b.theta - self.model.theta_offset - theta_shift, b.theta_dot, b.phi_dot, b.theta_ddot, b.phi_ddot]
        xd = [b.theta_dot, b.theta_ddot, b.phi_ddot, *self.jerks]
        if not phi_ddot:
            x[4], xd[4] = np.zeros_like(b.phi_ddot), np.zeros_like(b.phi_ddot)
        i = 1 if equation == ARM else 0
        out = pl.inverse_dynamics(*x)[i]
        if s.fine is not None:
            # F*f(x) = f(F*x) + (σ_F²/2)·ẋᵀ∇²f ẋ to second order in F's width: the curvature term from the
            # second difference of ID along the motion, ±σ_F·ẋ (exactly 0 for the terms linear in the states)
            h = b.filt.width
            up = pl.inverse_dynamics(*(a + h * d for a, d in zip(x, xd, strict=True)))[i]
            down = pl.inverse_dynamics(*(a - h * d for a, d in zip(x, xd, strict=True)))[i]
            out = 0.5 * (up + down)
        return s.product(out)

    @cached_property
    def jerks(self) -> tuple[np.ndarray, np.ndarray]:
        """(θ⃛, φ⃛) of the lightly smoothed states (for the curvature term of inverse_dynamics)."""
        b = self.fine
        return np.gradient(b.theta_ddot, self.prep.dt), np.gradient(b.phi_ddot, self.prep.dt)

    @cached_property
    def arm_known_friction(self) -> np.ndarray:
        """K * (the torque of the rig's own arm friction, spring and constant torque), from the shared laws: the sliding level for
        Coulomb/stiction (the regression's rows are sliding), LuGre's bristle state integrated along the measured φ̇."""
        a, f = self.arm, self.fine
        out = np.zeros(self.prep.n)
        fr = self.model.arm_friction
        if fr.viscous is not None:
            out += fr.viscous.torque(a.phi_dot)
        if fr.dry is not None:
            out += a.smooth(law_on_array(Coulomb(fr.dry.sliding_level).torque, self.arm_direction))
        if fr.lugre is not None:
            z, torque = 0.0, np.empty(self.prep.n)
            for k, v in enumerate(f.phi_dot):
                z, z_dot = fr.lugre.advance(z, float(v), self.prep.dt)
                torque[k] = fr.lugre.torque(z, z_dot, float(v))
            out += a.product(torque)
        if self.model.spring_k:
            out += -self.model.spring_k * (a.phi - self.model.spring_phi0)
        if self.model.arm_bias:  # the rig's own constant torque (the kernel integrates to one)
            out += self.model.arm_bias
        return out + self.known_joint_torque(ARM)

    def known_joint_torque(self, equation: str) -> np.ndarray | float:
        """K * (the torque of the rig's own torque-law effects on ``equation``'s joint; RigModel.joint_torques)."""
        own = [e for e in self.model.joint_torques if e.equation == equation]
        if not own:
            return 0.0
        f = self.fine
        x = (f.theta - self.model.theta_offset, f.theta_dot, f.phi, f.phi_dot)
        return self.states(equation).product(sum(e.torque(*x) for e in own))

    def joint_torque_columns(self, effect: type[JointTorque]) -> np.ndarray:
        """K * (a torque-law effect's basis, one column per parameter): the law evaluated on the instantaneous
        motion (the narrow kernel's states) and seen through its equation's kernel like every other column."""
        f = self.fine
        basis = effect.basis(f.theta - self.model.theta_offset, f.theta_dot, f.phi, f.phi_dot)
        s = self.states(effect.equation)
        return np.column_stack([s.product(np.broadcast_to(b, f.theta.shape).astype(float)) for b in basis])

    def lugre_params(self, params: dict[str, dict[str, float]], vs: float) -> dict[str, float]:
        """arm_lugre in the vocabulary from the regression's Coulomb level, viscous term and Stribeck peak; σ0 and σ1
        from the rig's [compensation.lugre] (the presliding displacement Fc/σ0 is far below one encoder count)."""
        cfg = self.rig.compensation.lugre
        fc = params.get("arm_coulomb", {}).get("Fc", self.known_value("arm_coulomb", "Fc"))
        fv = params.get("arm_viscous", {}).get("Fv", self.known_value("arm_viscous", "Fv"))
        peak = params["arm_lugre"].get("Fs_minus_Fc", 0.0)
        return {"sigma0": cfg.sigma0, "sigma1": cfg.sigma1, "Fc": fc, "Fs": fc + peak, "vs": vs, "Fv": max(fv, 0.0)}

    def stribeck(self, vs: float) -> np.ndarray:
        """K * (the Stribeck part of LuGre's steady-state friction, eq. 3 at constant speed, per unit Fs − Fc): the
        torque −e^(−(v/vs)²)·sgn v, from LuGre.steady_state_force, evaluated on the instantaneous motion (the direction
        from the encoder counts, the speed through the narrow kernel: a smoothed speed inside the law lags, which the
        regression would read as a delay) and then seen through the arm kernel like every other column."""
        key = f"stribeck:{vs:.6g}"
        if key not in self._columns:
            law = LuGre(sigma0=1.0, sigma1=0.0, Fc=0.0, Fs=1.0, vs=vs)
            v = self.arm_direction * np.abs(self.fine.phi_dot)
            self._columns[key] = self.arm.product(-law.steady_state_force(v))  # the law takes the array whole
        return self._columns[key]

    @cached_property
    def pend_known_friction(self) -> np.ndarray:
        """K * (the torque of the rig's own pendulum-pivot friction)."""
        p, f = self.pend, self.fine
        out = np.zeros(self.prep.n)
        fr = self.model.pendulum_friction
        if fr.viscous is not None:
            out += fr.viscous.torque(p.theta_dot)
        if fr.dry is not None:
            out += p.product(law_on_array(fr.dry.torque, f.theta_dot))
        return out + self.known_joint_torque(PEND)

    # ------------------------------------------------------------------ the command torque
    def command_torque(self, path: InputPath, equation: str = ARM) -> np.ndarray:
        """K * (torque the command produces through the actuator chain, with the rig's own gain)."""
        if equation == ARM and path in self._held:
            return self._held[path]
        shape_key = (path.deadzone, path.limit)
        tau0 = self._tau0.get(shape_key)
        if tau0 is None:
            a = self.model.actuator
            act = Actuator(kind=a.kind, motor=a.motor, gain=1.0, deadzone=path.deadzone, limit=path.limit)
            tau0 = piecewise_linear_on_array(lambda c: act.torque_terms(c)[0], self.prep.u, actuator_kinks(act))
            if len(self._tau0) < 256:
                self._tau0[shape_key] = tau0
        held = self.known_gain * self.states(equation).held(tau0, self.prep.command_lag + path.delay)
        if equation == ARM and len(self._held) < 1024:
            self._held[path] = held
        return held

    @cached_property
    def back_emf(self) -> float:
        """Viscous-like damping of a voltage-driven motor (N m s/rad), part of the nominal model."""
        return self.model.actuator.torque_terms(0.0)[1]

    def arm_residual(self, path: InputPath, d_inertia: float = 0.0) -> np.ndarray:
        """y_arm = ID_arm(J + ΔJ) + d·φ̇ − K*τ_command(path) − K*τ_known (d: back-EMF damping of a DC motor, τ_known:
        the rig's own arm friction and spring)."""
        y = self.arm_id + self.back_emf * self.arm.phi_dot - self.command_torque(path) - self.arm_known_friction
        return y + d_inertia * self.arm_dJ if d_inertia else y

    @cached_property
    def arm_dJ(self) -> np.ndarray:
        """∂ID_arm/∂J (ID is linear in J, so the difference quotient is exact)."""
        plant1 = FurutaPlant(self.plant.p.with_arm_inertia(0.0, INERTIA_STEP))
        return (self.inverse_dynamics(ARM, plant1) - self.arm_id) / INERTIA_STEP

    @cached_property
    def arm_pendulum_part(self) -> np.ndarray:
        """ID_arm with φ̈ = 0: the pendulum's reaction γ cos θ θ̈ and the velocity terms of eq. 4's arm row (the part
        an input gain would scale and an arm-inertia change would not)."""
        return self.inverse_dynamics(ARM, phi_ddot=False)

    @cached_property
    def arm_m22(self) -> np.ndarray:
        """K * M22(θ) of eq. 4, the arm's inertia as the arm equation sees it (from inverse_dynamics, on the states the
        nonlinear terms are evaluated on)."""
        th = self.arm.base.theta - self.model.theta_offset
        one, zero = np.ones_like(th), np.zeros_like(th)
        m22 = self.plant.inverse_dynamics(th, zero, zero, zero, one)[1]
        return self.arm.product(m22 - self.plant.inverse_dynamics(th, zero, zero, zero, zero)[1])

    def arm_weight(self, d_inertia: float) -> np.ndarray | float:
        """Residual weight M22_nominal / M22_model: the arm residual's noise is the encoder's φ̈ error times
        the model's inertia, so models with different inertias are compared in acceleration units."""
        return 1.0 if not d_inertia else self.arm_m22 / (self.arm_m22 + d_inertia)

    @cached_property
    def arm_id(self) -> np.ndarray:
        return self.inverse_dynamics(ARM)

    @cached_property
    def pend_id(self) -> np.ndarray:
        return self.inverse_dynamics(PEND)

    @cached_property
    def pend_residual(self) -> np.ndarray:
        """y_pend = ID_pend − K*τ_known (the rig's own pivot friction)."""
        return self.pend_id - self.pend_known_friction

    # ------------------------------------------------------------------ masks
    @cached_property
    def arm_still(self) -> np.ndarray:
        return self.stays(STILL_TICKS)

    def stays(self, ticks: int) -> np.ndarray:
        """Samples in runs of ≥ ``ticks`` ticks with the same encoder count: the arm is stuck, or moves too
        slowly for the encoder to resolve its acceleration. Runs at rest with nothing pushing the arm (no
        command, the pendulum still: before a step, say) are not counted: eq. 4 holds there as 0 = 0."""
        runs = self.count_runs
        still = np.repeat(runs, runs) >= ticks
        run_id = np.repeat(np.arange(len(runs)), runs)
        pushed = (self.prep.u != 0) | (np.abs(self.arm.theta_dot) > QUIET_THETA_DOT)
        pushed_run = np.bincount(run_id, weights=pushed.astype(float), minlength=len(runs)) > 0
        return still & pushed_run[run_id]

    def clear_of(self, mask: np.ndarray) -> np.ndarray:
        """Rows whose arm filter window holds no sample of ``mask``."""
        h = self.arm.filt.half + 2
        return np.convolve(mask.astype(float), np.ones(2 * h + 1), mode="same") == 0

    @cached_property
    def arm_direction(self) -> np.ndarray:
        """Direction of the arm's motion (±1) from the encoder counts: the sign of the last count change;
        inside a run of equal counts entered and left through the same edge (a reversal within one count)
        the switch is put at the run's middle, where a turning point is, by symmetry."""
        cnt = np.round(self.prep.phi / self.prep.phi_lsb).astype(np.int64)
        d = np.diff(cnt)
        idx = np.flatnonzero(d)
        out = np.sign(self.fine.phi_dot)
        if len(idx) < 2:
            return out
        step = np.sign(d[idx])  # direction of each count change (between samples idx and idx+1)
        out[: idx[0] + 1] = step[0]
        for j in range(len(idx) - 1):
            a, b = idx[j] + 1, idx[j + 1] + 1  # run of equal counts: samples a … b−1
            if step[j] == step[j + 1]:
                out[a:b] = step[j]
            else:
                mid = (a + b) // 2
                out[a:mid] = step[j]
                out[mid:b] = step[j + 1]
        out[idx[-1] + 1 :] = step[-1]
        return out

    @cached_property
    def arm_travel(self) -> tuple[float, float]:
        """(lowest, highest) arm angle over the usable part of the recording (φ as signals.canonical_angles put it)."""
        phi = self.prep.phi[self.prep.valid]
        return float(np.min(phi)), float(np.max(phi))

    @cached_property
    def arm_rows(self) -> np.ndarray:
        """Rows of the arm equation whose filter window sees the arm sliding (no still run inside); none when
        the arm hardly moves at all (less than MIN_ARM_TRAVEL encoder counts end to end)."""
        if not self.prep.moves(self.prep.phi):
            return np.zeros(self.prep.n, dtype=bool)
        return self.prep.valid & self.clear_of(self.arm_still)

    @cached_property
    def count_runs(self) -> np.ndarray:
        """Lengths of the runs of equal encoder counts of φ, in time order."""
        cnt = np.round(self.prep.phi / self.prep.phi_lsb).astype(np.int64)
        start = np.flatnonzero(np.concatenate([[True], np.diff(cnt) != 0]))
        return np.diff(np.concatenate([start, [len(cnt)]]))

    @cached_property
    def pend_rows(self) -> np.ndarray:
        """Rows of the pendulum equation, less those whose filter window holds the start or end of a slow stretch (a
        run of ≥ SLOW_TICKS at one count). There the encoder's quantisation error is a slow ramp and step, which the
        kernel passes as a false φ̈ (it enters through γ cos θ φ̈); inside a stick φ is exactly constant (kept), and
        in fast motion the error is white and filtered out."""
        runs = self.count_runs
        slow = np.repeat(runs, runs) >= SLOW_TICKS
        edges = np.zeros(self.prep.n)
        edges[np.flatnonzero(np.diff(slow.astype(int)))] = 1.0
        h = self.pend.filt.half + 2
        near = np.convolve(edges, np.ones(2 * h + 1), mode="same") > 0
        return self.prep.valid & ~near


STILL_TICKS = 10
STICTION_STILL_TICKS = 5  # with a breakaway torque above the sliding level, even a short stay may be a stick
SLOW_TICKS = 100  # a run this long at one count (0.2 s at 500 Hz): a stick, or motion slow enough for the kernel to pass
# the quantisation error's ramp
QUIET_THETA_DOT = 0.05  # rad/s: a pendulum slower than this hardly pushes the arm


@dataclass(frozen=True)
class Candidate:
    """One named effect of the registry (furuta_rt.model.effects.EFFECT_TYPES) as the regression sees it: its row of
    eq. 4, size parameter, look-alikes and how it enters the residual (columns, parameters from the fit, plausibility,
    nonlinear parameter) are all the registry class's; the candidate caches its columns per recording."""

    name: str

    @property
    def effect(self) -> type[Effect]:
        return EFFECT_TYPES[self.name]

    @property
    def equation(self) -> str:
        return self.effect.equation

    @property
    def searched(self) -> bool:
        """Tried on every recording (the registry's ``searched``), or only when asked."""
        return bool(self.effect.searched)

    @property
    def main(self) -> str:
        return self.effect.main

    @property
    def lookalikes(self) -> tuple[str, ...]:
        return self.effect.lookalikes

    @property
    def nonlinear(self) -> str | None:
        """The nonlinear parameter it moves (selection.Spec.with_value's kind), or None."""
        return self.effect.nonlinear

    @property
    def requires(self) -> str | None:
        return self.effect.requires

    @property
    def excludes(self) -> tuple[str, ...]:
        return self.effect.excludes

    def columns(self, ctx: Context, path: InputPath, vs: float = 0.0) -> np.ndarray:
        """(n, k) regressors for this effect's linear parameters (k = 0 for pure input-path effects)."""
        if self.effect.varying:
            return self.effect.columns(ctx, path, vs)
        cached = ctx._columns.get(self.name)
        if cached is None:
            cached = ctx._columns[self.name] = self.effect.columns(ctx, path, vs)
        return cached

    def params(self, coef: np.ndarray, path: InputPath, gain: float, ctx: Context, d_inertia: float = 0.0) -> dict[str, float]:
        """SI parameters in the diagnose JSON names from the fitted coefficients (totals; ``gain``: the total input
        gain)."""
        return self.effect.from_fit(coef, ctx, path, gain, d_inertia)

    def plausible(self, par: dict[str, float], rig: RigConfig, travel: tuple[float, float] | None = None) -> bool:
        """Physically admissible values (friction opposes motion, springs restore, inertia positive); ``travel``:
        Context.arm_travel."""
        return self.effect.plausible(par, rig, travel)


def nominal_latency(rig: RigConfig) -> float:
    """The rig's own latency from the sample instant to the torque (s): effects.total_latency of its configuration."""
    return total_latency(rig.effects, rig.control.command_delay_ticks, rig.control.rate_hz)


KINK_MARGIN = 0.02  # a command within this share of a kink is on neither side of it
KINK_MIN_SAMPLES, KINK_MIN_SHARE = 10, 0.005  # the commands needed on each side of a kink (count, share of the rows)


def kink_supported(u: np.ndarray, kink: float) -> bool:
    """Whether commands ``u`` (command units, the equation's rows) lie on both sides of a kink at |u| = ``kink`` of the
    command → torque map (a deadzone edge, a saturation onset): nonzero ones below it and ones above it, each on at
    least KINK_MIN_SAMPLES and KINK_MIN_SHARE of the rows. On one side only the kink is a gain change or a constant
    torque (a step of one level: a saturation at that level, or a deadzone below it, is an input gain)."""
    a = np.abs(np.asarray(u, float))
    need = max(KINK_MIN_SAMPLES, KINK_MIN_SHARE * len(a))
    below = np.count_nonzero((a > 0) & (a < (1 - KINK_MARGIN) * kink))
    above = np.count_nonzero(a > (1 + KINK_MARGIN) * kink)
    return kink > 0 and below >= need and above >= need


INERTIA_STEP = 1e-3  # kg m², for the derivative of ID with respect to J (ID is linear in J: exact)

CANDIDATES: dict[str, Candidate] = {name: Candidate(name) for name, cls in EFFECT_TYPES.items() if cls.regressed}
"""The regression's candidates: every registered effect it measures, in the registry's order (the order it tries them)."""
