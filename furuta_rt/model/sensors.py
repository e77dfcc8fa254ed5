"""The rig's measurement path (thesis section 3.3, appendix B) and the DAQ calibration.

θ and θ̇ come from an analog 2nd-order Bessel low-pass and its differentiator output:

    θ_f = H(s)·θ,   θ̇_f = s·H(s)·θ,   H(s) = 3w² / (s² + 3ws + 3w²),   w = ω_c / 1.3617

(ω_c is the −3 dB frequency; 1.3617 rad/s is the −3 dB point of the normalised Bessel 3/(s²+3s+3)).
φ comes from an incremental encoder. The DAQ digitises θ_f and θ̇_f with an ADC.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

BESSEL2_CUTOFF_FACTOR = 1.3617


def count_of(x: np.ndarray | float, step: float, phase: float = 0.0) -> np.ndarray:
    """The count a quantiser of ``step`` units per count reads for ``x``: the nearest level (ties up), its grid shifted
    by ``phase`` counts (an encoder's or an ADC's unknown sub-count phase)."""
    if type(x) is float:  # one reading (the DAQ's tick): the same arithmetic without numpy's per-call cost
        return float(math.floor(x / step + phase + 0.5))  # type: ignore[return-value]
    return np.floor(np.asarray(x, dtype=float) / step + phase + 0.5)


def quantise(x: np.ndarray | float, step: float, phase: float = 0.0) -> np.ndarray:
    """The quantiser's reading of ``x`` in ``x``'s units: its count (``count_of``) times ``step``, on the shifted grid."""
    return step * (count_of(x, step, phase) - phase)


@dataclass(slots=True)
class Measurement:
    """One tick's measurement in SI: θ_f and θ̇_f from the analog path, φ from the encoder."""

    t: float
    theta: float
    theta_dot: float
    phi: float


@dataclass(frozen=True, slots=True)
class BesselPath:
    """Second-order Bessel low-pass with −3 dB at ``cutoff`` rad/s, and its derivative channel."""

    cutoff: float

    def __post_init__(self) -> None:
        if not self.cutoff > 0:
            raise ValueError(f"Bessel cutoff must be > 0 rad/s, got {self.cutoff}")

    @property
    def w(self) -> float:
        return self.cutoff / BESSEL2_CUTOFF_FACTOR

    def coefficients(self) -> tuple[float, float]:
        """(a1, a0) of the denominator s² + a1 s + a0; the numerator is a0."""
        w = self.w
        return 3.0 * w, 3.0 * w * w

    def response(self, omega: np.ndarray | float) -> np.ndarray:
        """Complex frequency response H(jω) of the θ channel."""
        a1, a0 = self.coefficients()
        s = 1j * np.asarray(omega, dtype=float)
        return a0 / (s * s + a1 * s + a0)

    def state_space(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(A, B, C) with state [θ_f, θ̇_f], input θ, outputs both states (C = I)."""
        a1, a0 = self.coefficients()
        A = np.array([[0.0, 1.0], [-a0, -a1]])
        B = np.array([[0.0], [a0]])
        return A, B, np.eye(2)

    def derivative(self, theta: float, y: float, y_dot: float) -> float:
        """ÿ of the filter state for input θ (scalar hot path)."""
        a1, a0 = self.coefficients()
        return a0 * (theta - y) - a1 * y_dot


@dataclass(frozen=True, slots=True)
class Calibration:
    """Raw DAQ counts ⇄ SI. Sent by the device in HELLO_ACK, so host and device agree."""

    theta_rad_per_count: float = 2.0 * math.pi / 65536.0
    theta_offset_counts: int = 0
    theta_dot_rad_s_per_count: float = 100.0 / 65536.0
    phi_counts_per_rev: int = 4096
    adc_bits: int = 16
    theta_wraps: bool = False  # the θ channel wraps modulo its range (a full-turn sensor) instead of saturating

    def __post_init__(self) -> None:
        if self.theta_rad_per_count <= 0 or self.theta_dot_rad_s_per_count <= 0:
            raise ValueError("ADC scales must be > 0")
        if self.phi_counts_per_rev <= 0:
            raise ValueError(f"encoder counts per revolution must be > 0, got {self.phi_counts_per_rev}")

    @property
    def adc_max(self) -> int:
        return (1 << (self.adc_bits - 1)) - 1

    @property
    def adc_min(self) -> int:
        return -(1 << (self.adc_bits - 1))

    @property
    def phi_rad_per_count(self) -> float:
        return 2.0 * math.pi / self.phi_counts_per_rev

    def to_si(self, theta_adc: int, theta_dot_adc: int, phi_count: int) -> tuple[float, float, float]:
        return (
            (theta_adc - self.theta_offset_counts) * self.theta_rad_per_count,
            theta_dot_adc * self.theta_dot_rad_s_per_count,
            phi_count * self.phi_rad_per_count,
        )

    def quantize_adc(self, value: float, scale: float) -> tuple[int, bool]:
        """(count, overrange) of an ADC reading ``value`` with ``scale`` units per count."""
        c = int(count_of(value, scale))
        if c > self.adc_max:
            return self.adc_max, True
        if c < self.adc_min:
            return self.adc_min, True
        return c, False

    def to_counts(self, theta_f: float, theta_dot_f: float, phi: float) -> tuple[int, int, int, bool]:
        """(θ, θ̇, φ counts, overrange) as the DAQ would read them."""
        if self.theta_wraps:
            span = 1 << self.adc_bits
            t = (int(count_of(theta_f, self.theta_rad_per_count)) - self.adc_min) % span + self.adc_min
            o1 = False
        else:
            t, o1 = self.quantize_adc(theta_f, self.theta_rad_per_count)
        td, o2 = self.quantize_adc(theta_dot_f, self.theta_dot_rad_s_per_count)
        return t + self.theta_offset_counts, td, int(count_of(phi, self.phi_rad_per_count)), o1 or o2
