"""Friction compensation F̂ in u = L·x + F̂ (thesis section 7), built on the friction laws of
furuta_rt.model.friction — the same objects that act as friction in the simulator.

Modes: ``none``; ``coulomb`` (eq. 1, F̂ = Fc·sat(φ̂̇/ε)); ``stiction`` (eq. 2 with the controller's
own torque as the external torque F_e); ``lugre`` (eq. 3, the bristle state integrated on φ̂̇);
``adaptive`` (eq. 1 with Fc estimated online while balancing, ``AdaptiveCoulomb``; the thesis'
section 8 asks for "some kind of adaptation for this parameter"). ``coulomb`` and ``stiction`` add
a viscous part Fv·φ̂̇ when the configuration (or a diagnosis report, --comp-from) gives one.
"""

from __future__ import annotations

from furuta_rt.config import CompensationConfig, CompMode
from furuta_rt.model.friction import Coulomb, CoulombStiction, LuGre, Viscous


class AdaptiveCoulomb:
    """Online estimate F̂c of the arm's Coulomb level; compensation F̂ = F̂c·sat(φ̂̇/ε) (eq. 1).

    The information is the arm observer's own velocity correction. The observer is driven by the net
    torque u − F̂, i.e. it assumes the compensation cancels the friction exactly; the torque the arm
    really felt differs by r = (F̂c − Fc)·sgn(φ̇), and the observer's φ̇ correction k₁·e (e = φ − φ̂⁻,
    the innovation) is r's effect on the arm speed over the tick, so r̂ = k₁·e / b (b: arm speed per
    N m over one tick, the observer's Bd[1, 1]). The estimate follows a gradient law, applied once per
    window of W ticks in which the arm slid one way (s = ±1):

        F̂c ← proj_[0, Fc_max]( F̂c − (h / T_a) · s · Σ_window r̂ ),

    which with V = (F̂c − Fc)²/2 gives dV/dt = −(F̂c − Fc)²/T_a ≤ 0 while the arm slides (the projection
    only lowers V): F̂c converges exponentially with time constant T_a of sliding time.

    Why this law and not recursive least squares on the arm equation's residual: the regressor is the
    single bounded sign s, so RLS would reduce to a running mean whose gain decays (or, with a forgetting
    factor, winds its covariance up while the estimate is frozen, making the next step jumpy). The
    fixed-gain law has one tuning knob with a physical meaning (T_a), a known re-convergence time after a
    friction change, needs no φ̈ (which a 4096-count encoder cannot give), and costs a few additions per
    tick. The per-tick r̂ is noisy (encoder quantisation alone gives ~0.4 N m on the thesis rig); T_a
    averages it.

    Frozen: outside balancing and swing-up (only ``Controller.update`` calls ``adapt``, and not while
    swinging); in any window where φ̂̇ changed sign (a reversal: the command delay and the observer's
    transient mix the two signs, and the sign of φ̇ is uncertain near it); and in any window where the
    encoder moved less than v_min·W·h (the arm may have stuck, where friction is not ±Fc). The estimate
    is kept across re-arming; ``reset`` clears only the window.

    Measured (simulated thesis rig, arm Coulomb 0.35 N m, defaults T_a = 0.5 s, v_min = 0.05 rad/s,
    W = 25): within 10 % after 1.3 s; over 30–60 s a mean of 0.352 N m (std 0.005), std θ / std φ 0.00145
    rad / 0.0161 rad against 0.00147 / 0.0174 with the exact fixed compensator. Choosing single ticks by
    their own φ̂̇ instead of whole windows made F̂c creep 5–8 % high (a slow arm crosses encoder counts,
    φ̂̇ jumps at each count and the innovations that follow are negative; with a 2²² count encoder the
    creep vanished); over a window the residuals sum to the observer's total speed correction, where a
    count enters only at the two ends.
    """

    __slots__ = ("_n", "_phi0", "_rate", "_sign", "_sum", "_unit", "_v_min", "_window", "fc_hat", "fc_max")

    def __init__(self, fc0: float, fc_max: float, time_constant: float, epsilon: float, v_min: float,
                 window_ticks: int, period: float) -> None:
        if not 0.0 <= fc0 <= fc_max:
            raise ValueError(f"adaptive compensation needs 0 <= Fc0 <= Fc_max, got Fc0={fc0}, Fc_max={fc_max}")
        self._unit = Coulomb(Fc=1.0, epsilon=epsilon)  # eq. 1 is linear in Fc: F̂ = F̂c · (unit law's F̂)
        self._rate = period / time_constant
        self._v_min = v_min * window_ticks * period  # as the displacement over a window, rad
        self._window = max(1, window_ticks)
        self.fc_max = fc_max
        self.fc_hat = fc0
        self.reset()

    def reset(self) -> None:
        self._sign = 0.0
        self._n = 0
        self._sum = 0.0
        self._phi0 = 0.0

    def compensation(self, v_hat: float) -> float:
        return self.fc_hat * self._unit.compensation(v_hat)

    def adapt(self, torque_residual: float, v_hat: float, phi: float) -> None:
        """Collect the tick's arm-torque residual r̂ (N m) with the prior estimate φ̂̇⁻ (rad/s) and the measured φ;
        the estimate moves once per window of ``window_ticks`` ticks in which φ̂̇⁻ kept one sign and the encoder
        moved at least v_min·window (the window's mean residual, times its sign, times window·h/T_a).

        Whole windows, not single ticks: a slow arm crosses encoder counts every few ticks, φ̂̇ jumps at each
        count and the innovations after it are negative; choosing single ticks by their φ̂̇ made F̂c creep 5–8 %
        high (none with a fine encoder). Over a window the residuals sum to the observer's total speed
        correction, where a count only enters at the two ends."""
        sign = 1.0 if v_hat > 0.0 else (-1.0 if v_hat < 0.0 else 0.0)
        if sign == 0.0 or sign != self._sign:  # a reversal (or rest): a new window on the new side
            self._sign = sign
            self._n = 0
            self._sum = 0.0
            self._phi0 = phi
            return
        self._sum += torque_residual
        self._n += 1
        if self._n < self._window:
            return
        moved = (phi - self._phi0) * sign
        total = self._sum
        self._n = 0
        self._sum = 0.0
        self._phi0 = phi
        if moved < self._v_min:  # too slow to be sure it slid the whole window (it may have stuck)
            return
        fc = self.fc_hat - self._rate * total * sign
        self.fc_hat = 0.0 if fc < 0.0 else (self.fc_max if fc > self.fc_max else fc)


class Compensator:
    """Computes F̂ from the estimated arm velocity every tick."""

    __slots__ = ("_h", "_law", "_lugre", "_viscous", "adaptive", "mode", "z")

    def __init__(
        self,
        mode: CompMode,
        law: Coulomb | CoulombStiction | LuGre | AdaptiveCoulomb | None,
        period: float,
        viscous: Viscous | None = None,
    ) -> None:
        if mode != "none" and law is None:
            raise ValueError(f"compensation mode {mode!r} needs a friction law")
        self.mode = mode
        self._law = law
        self._viscous = viscous if viscous is not None and viscous.Fv > 0.0 else None
        self.adaptive = law if isinstance(law, AdaptiveCoulomb) else None
        self._lugre = law if isinstance(law, LuGre) else None  # the type looked up once, not every tick
        self._h = period
        self.z = 0.0

    @classmethod
    def from_config(cls, cfg: CompensationConfig, period: float, mode: CompMode | None = None) -> Compensator:
        mode = mode or cfg.mode
        law: Coulomb | CoulombStiction | LuGre | AdaptiveCoulomb | None
        viscous: Viscous | None = None
        if mode == "coulomb":
            law = Coulomb(Fc=cfg.coulomb.Fc, epsilon=cfg.coulomb.epsilon)
            viscous = Viscous(cfg.coulomb.Fv)
        elif mode == "stiction":
            law = CoulombStiction(Fc=cfg.stiction.Fc, Fs=max(cfg.stiction.Fs, cfg.stiction.Fc), v_zero=cfg.stiction.v_zero)
            viscous = Viscous(cfg.stiction.Fv)
        elif mode == "lugre":
            c = cfg.lugre
            law = LuGre(sigma0=c.sigma0, sigma1=c.sigma1, Fc=c.Fc, Fs=max(c.Fs, c.Fc), vs=c.vs, Fv=c.Fv)
        elif mode == "adaptive":
            a = cfg.adaptive
            law = AdaptiveCoulomb(a.Fc0, a.Fc_max, a.time_constant, a.epsilon, a.v_min, a.window_ticks, period)
        else:
            law = None
        return cls(mode, law, period, viscous)

    @property
    def law(self) -> Coulomb | CoulombStiction | LuGre | AdaptiveCoulomb | None:
        return self._law

    @property
    def coulomb_level(self) -> float:
        """The Coulomb level Fc the compensator uses now (the estimate in ``adaptive`` mode; 0 for ``none``)."""
        law = self._law
        if law is None:
            return 0.0
        if isinstance(law, AdaptiveCoulomb):
            return law.fc_hat
        return law.Fc

    def reset(self) -> None:
        self.z = 0.0
        if self.adaptive is not None:
            self.adaptive.reset()

    def __call__(self, v_hat: float, u_lin: float) -> float:
        """F̂ for this tick from the estimated arm velocity φ̂̇ (``v_hat``) and the linear command ``u_lin`` (the
        external torque of eq. 2); LuGre's bristle state advances by one period."""
        lugre = self._lugre
        if lugre is not None:
            z, z_dot = lugre.advance(self.z, v_hat, self._h)
            self.z = z
            return lugre.force(z, z_dot, v_hat)
        law = self._law
        if law is None:
            return 0.0
        out = law.compensation(v_hat) if isinstance(law, AdaptiveCoulomb) else law.compensation(v_hat, u_lin)
        viscous = self._viscous
        return out if viscous is None else out + viscous.compensation(v_hat)
