"""The recent balancing trace the control loop keeps for the end-of-run summary (its limit cycles:
furuta_rt.runtime.summary)."""

from __future__ import annotations

import numpy as np


class RecentTrace:
    """The last ``capacity`` (t, θ, φ) samples of balancing, in preallocated lists used as a ring: one store
    per value and tick in the control loop, nothing allocated that grows."""

    __slots__ = ("capacity", "n", "phi", "t", "theta")

    def __init__(self, capacity: int = 60_000) -> None:
        self.capacity = capacity
        self.n = 0
        self.t = [0.0] * capacity
        self.theta = [0.0] * capacity
        self.phi = [0.0] * capacity

    def add(self, t: float, theta: float, phi: float) -> None:
        i = self.n % self.capacity
        self.t[i] = t
        self.theta[i] = theta
        self.phi[i] = phi
        self.n += 1

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(t, θ, φ) in time order."""
        k = min(self.n, self.capacity)
        start = self.n % self.capacity if self.n > self.capacity else 0
        order = (np.arange(k) + start) % self.capacity
        return tuple(np.asarray(v)[order] for v in (self.t, self.theta, self.phi))  # type: ignore[return-value]
