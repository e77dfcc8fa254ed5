"""A recording of the rig: the columns every tool speaks (t, θ, θ̇, φ, u in SI; θ = 0 upright).

``theta`` and ``theta_dot`` are as measured (through the rig's analog path); ``u`` is the torque
command on the arm (N m), or the motor voltage for a voltage-driven rig. Optional ``extra`` columns
carry what a closed-loop run also knows (estimated φ̇, the parts of u, true states in simulation).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class Recording:
    t: np.ndarray
    theta: np.ndarray
    phi: np.ndarray
    u: np.ndarray
    theta_dot: np.ndarray | None = None
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    meta: dict[str, object] = field(default_factory=dict)

    def __post_init__(self) -> None:
        n = len(self.t)
        for name in ("theta", "phi", "u"):
            if len(getattr(self, name)) != n:
                raise ValueError(f"column {name!r} has {len(getattr(self, name))} rows, t has {n}")
        if self.theta_dot is not None and len(self.theta_dot) != n:
            raise ValueError("column 'theta_dot' has a different length than t")

    def __len__(self) -> int:
        return len(self.t)

    @property
    def dt(self) -> float:
        """Median sample period (s)."""
        return float(np.median(np.diff(self.t))) if len(self.t) > 1 else 0.0

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0]) if len(self.t) else 0.0

    def slice(self, start: int, stop: int) -> Recording:
        return Recording(
            t=self.t[start:stop],
            theta=self.theta[start:stop],
            phi=self.phi[start:stop],
            u=self.u[start:stop],
            theta_dot=None if self.theta_dot is None else self.theta_dot[start:stop],
            extra={k: v[start:stop] for k, v in self.extra.items()},
            meta=dict(self.meta),
        )
