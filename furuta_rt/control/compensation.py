"""Friction compensation F̂ in u = L·x + F̂ (thesis section 7), built on the friction laws of
furuta_rt.model.friction — the same objects that act as friction in the simulator.

Modes: ``none``; ``coulomb`` (eq. 1, F̂ = Fc·sat(φ̂̇/ε)); ``stiction`` (eq. 2 with the controller's
own torque as the external torque F_e); ``lugre`` (eq. 3, the bristle state integrated on φ̂̇).
"""

from __future__ import annotations

from furuta_rt.config import CompensationConfig, CompMode
from furuta_rt.model.friction import Coulomb, CoulombStiction, LuGre


class Compensator:
    """Computes F̂ from the estimated arm velocity every tick."""

    __slots__ = ("_h", "_law", "mode", "z")

    def __init__(self, mode: CompMode, law: Coulomb | CoulombStiction | LuGre | None, period: float) -> None:
        if mode != "none" and law is None:
            raise ValueError(f"compensation mode {mode!r} needs a friction law")
        self.mode = mode
        self._law = law
        self._h = period
        self.z = 0.0

    @classmethod
    def from_config(cls, cfg: CompensationConfig, period: float, mode: CompMode | None = None) -> Compensator:
        mode = mode or cfg.mode
        law: Coulomb | CoulombStiction | LuGre | None
        if mode == "coulomb":
            law = Coulomb(Fc=cfg.coulomb.Fc, epsilon=cfg.coulomb.epsilon)
        elif mode == "stiction":
            law = CoulombStiction(Fc=cfg.stiction.Fc, Fs=max(cfg.stiction.Fs, cfg.stiction.Fc), v_zero=cfg.stiction.v_zero)
        elif mode == "lugre":
            c = cfg.lugre
            law = LuGre(sigma0=c.sigma0, sigma1=c.sigma1, Fc=c.Fc, Fs=max(c.Fs, c.Fc), vs=c.vs, Fv=c.Fv)
        else:
            law = None
        return cls(mode, law, period)

    @property
    def law(self) -> Coulomb | CoulombStiction | LuGre | None:
        return self._law

    def reset(self) -> None:
        self.z = 0.0

    def __call__(self, v_hat: float, u_lin: float) -> float:
        law = self._law
        if law is None:
            return 0.0
        if isinstance(law, LuGre):
            self.z, z_dot = law.advance(self.z, v_hat, self._h)
            return law.force(self.z, z_dot, v_hat)
        return law.compensation(v_hat, u_lin)
