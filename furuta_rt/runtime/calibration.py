"""Start-up calibration for a swing-up: θ's zero from the pendulum hanging at rest, and the arm's zero.

For ``calibration_s`` (about a second) the loop feeds the device's θ and φ (SI, before this calibration) while the
actuator is off. The pendulum must hang still: the spread of θ and of φ over the window at most ``still_theta``,
and the mean θ within ``hanging_tolerance`` of π (upright is π away from hanging). Then

    θ_zero = wrap(mean θ − π),   φ_zero = mean φ,   θ_cal = wrap(θ − θ_zero),   φ_cal = φ − φ_zero

(the mean of θ taken around its first sample, so a reading that wraps at ±π averages right). Otherwise the
calibration is refused with a message that says what moved or where θ was. The result goes into the log's
"calibration" metadata record and replay applies it (furuta_rt.replay.core).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from furuta_rt.config import SwingUpConfig
from furuta_rt.controller.swingup import wrap_angle

CALIBRATION_METADATA = "calibration"


@dataclass(frozen=True, slots=True)
class StartupCalibration:
    """θ and φ zeros (rad) to subtract from the device's readings."""

    theta_zero: float = 0.0
    phi_zero: float = 0.0
    theta_spread: float = 0.0  # rad, over the window
    phi_spread: float = 0.0
    samples: int = 0

    def apply(self, theta: float, phi: float) -> tuple[float, float]:
        """(θ, φ) with the zeros removed, θ wrapped to [−π, π)."""
        return wrap_angle(theta - self.theta_zero), phi - self.phi_zero

    def metadata(self) -> dict[str, str]:
        """The log's "calibration" metadata record (MCAP metadata values are strings; repr keeps every bit)."""
        return {"theta_zero": repr(self.theta_zero), "phi_zero": repr(self.phi_zero),
                "theta_spread": repr(self.theta_spread), "phi_spread": repr(self.phi_spread),
                "samples": str(self.samples), "method": "hanging at rest: theta_zero = wrap(mean theta - pi)"}

    @classmethod
    def from_metadata(cls, meta: dict[str, str]) -> StartupCalibration:
        return cls(float(meta["theta_zero"]), float(meta["phi_zero"]), float(meta.get("theta_spread", "0")),
                   float(meta.get("phi_spread", "0")), int(meta.get("samples", "0")))

    def describe(self) -> str:
        return (f"calibrated: θ zero {self.theta_zero:+.4f} rad from hanging (θ spread {self.theta_spread:.4f} rad), "
                f"arm zero {self.phi_zero:+.4f} rad, over {self.samples} samples")


class CalibrationWindow:
    """Collects the window's samples; ``add`` returns True when it is full, then ``result`` decides."""

    __slots__ = ("_cfg", "_n", "_need", "_ph", "_ph_max", "_ph_min", "_th", "_th0", "_th_max", "_th_min")

    def __init__(self, cfg: SwingUpConfig, rate_hz: float) -> None:
        self._cfg = cfg
        self._need = max(2, round(cfg.calibration_s * rate_hz))
        self._n = 0
        self._th0 = self._th = self._ph = 0.0
        self._th_min = self._th_max = self._ph_min = self._ph_max = 0.0

    def add(self, theta: float, phi: float) -> bool:
        if self._n == 0:
            self._th0 = theta
            self._ph_min = self._ph_max = phi
        d = wrap_angle(theta - self._th0)
        self._th += d
        self._ph += phi
        self._th_min, self._th_max = min(self._th_min, d), max(self._th_max, d)
        self._ph_min, self._ph_max = min(self._ph_min, phi), max(self._ph_max, phi)
        self._n += 1
        return self._n >= self._need

    def result(self) -> StartupCalibration | str:
        """The calibration, or why it is refused (one line)."""
        cfg, n = self._cfg, self._n
        th_spread, ph_spread = self._th_max - self._th_min, self._ph_max - self._ph_min
        mean_theta = wrap_angle(self._th0 + self._th / n)
        if th_spread > cfg.still_theta or ph_spread > cfg.still_theta:
            return (f"calibration refused: the pendulum is not hanging still (over {n} samples θ moved "
                    f"{th_spread:.3f} rad and φ {ph_spread:.3f} rad, at most {cfg.still_theta:g} rad); let it come "
                    "to rest and start again")
        off = wrap_angle(mean_theta - math.pi)
        if abs(off) > cfg.hanging_tolerance:
            return (f"calibration refused: θ reads {mean_theta:+.3f} rad at rest, {abs(off):.3f} rad from hanging "
                    f"(π; at most {cfg.hanging_tolerance:g} rad): let the pendulum hang down, or check θ's sensor zero")
        return StartupCalibration(off, self._ph / n, th_spread, ph_spread, n)
