"""The recent balancing trace the control loop keeps for the end-of-run summary (its limit cycles:
furuta_rt.runtime.summary)."""

from __future__ import annotations

from array import array

import numpy as np


class RecentTrace:
    """The last ``capacity`` (t, θ, φ) samples of balancing, in preallocated arrays of doubles used as a ring: one
    store per value and tick in the control loop, nothing allocated. (A list would hold a new float object per
    store: 72 bytes a tick kept until the ring wraps, a control process growing by 4 MB a minute at 1 kHz.)"""

    __slots__ = ("capacity", "n", "phi", "t", "theta")

    def __init__(self, capacity: int = 60_000) -> None:
        self.capacity = capacity
        self.n = 0
        self.t = array("d", bytes(8 * capacity))
        self.theta = array("d", bytes(8 * capacity))
        self.phi = array("d", bytes(8 * capacity))

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
        return tuple(np.frombuffer(v)[order] for v in (self.t, self.theta, self.phi))  # type: ignore[return-value]
