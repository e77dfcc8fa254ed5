"""The sensor noise of a recording, estimated from the recording itself (the noise floor's noise model).

Above the dynamics band (SPECTRUM_FROM Hz up to 0.9 × Nyquist) a balanced or swinging pendulum barely moves, so the
spectra of the θ and θ̇ channels there are noise alone. Two kinds of noise reach them through different shapes:

* noise at the ADC (and its quantisation), white: a flat power spectrum in each channel (a_θ, a_θ̇);
* noise that enters *before* the analog Bessel filter (a potentiometer and its wiring), white there: shaped by the
  filter's response in θ_f (|H|²) and by its derivative in θ̇_f (|ω H|²) — one source, the same level b in both
  channels, coherent between them (θ̇_f is the filter's derivative state, thesis section 3.3).

P_θ(f) = a_θ + b |H(jω)|², P_θ̇(f) = a_θ̇ + b |ω H(jω)|² (each with its aliases at f + k·fs) are fitted jointly by
non-negative least squares in relative error (each Welch bin weighted by its own power). The ADC levels are what is
left after the quantisation the floor's Monte Carlo adds itself (step²/12). Without a Bessel path the θ channel's
model is the flat part alone; a θ channel read by an encoder (no noise beyond its quantisation) and a recording too
slow to have a band above the dynamics keep the config's values.

The config's noise values are the prior: they are used where the data cannot speak, and a disagreement of more
than DISAGREE × in the in-band rms is said in the notes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import optimize, signal

from furuta_rt.config import RigConfig
from furuta_rt.diagnose.regression.states import Prepared
from furuta_rt.model.sensors import BesselPath

SPECTRUM_FROM = 30.0  # Hz: above it the pendulum's motion is far below the sensors' noise
MIN_BINS = 8  # Welch bins in the band for a fit
DISAGREE = 2.0  # config vs data in-band rms ratio said in the notes
ALIASES = 8  # images of the sampled pre-filter noise counted in its spectral shape
FINE = 8  # the pre-filter noise is made at FINE × the recording's rate, then sampled


@dataclass(frozen=True)
class NoiseModel:
    """White ADC noise on θ_f and θ̇_f (std per sample) and white noise before the Bessel filter (two-sided power
    spectral density, rad²·s); ``source`` is "recording" or "config"."""

    theta_adc: float
    theta_dot_adc: float
    prefilter_psd: float
    source: str
    note: str = ""

    def sample(self, n: int, dt: float, bessel: BesselPath | None, rng: np.random.Generator,
               with_rate: bool) -> tuple[np.ndarray, np.ndarray | None]:
        """One draw of the θ_f and θ̇_f noise on a grid of ``n`` samples ``dt`` apart."""
        th = self.theta_adc * rng.standard_normal(n)
        thd = self.theta_dot_adc * rng.standard_normal(n) if with_rate else None
        if self.prefilter_psd > 0 and bessel is not None:
            y, yd = prefiltered(n, dt, bessel, self.prefilter_psd, rng)
            th = th + y
            if thd is not None:
                thd = thd + yd
        return th, thd

    def rms(self, dt: float, bessel: BesselPath | None) -> float:
        """The θ_f noise's rms (ADC and pre-filter parts)."""
        pre = 0.0
        if self.prefilter_psd > 0 and bessel is not None:
            f = np.linspace(0.0, 0.5 / dt, 4001)
            pre = float(np.trapezoid(2 * self.prefilter_psd * np.abs(bessel.response(2 * np.pi * f)) ** 2, f))
        return math.sqrt(self.theta_adc**2 + pre)


def prefiltered(n: int, dt: float, bessel: BesselPath, psd: float, rng: np.random.Generator
                ) -> tuple[np.ndarray, np.ndarray]:
    """White noise of two-sided density ``psd`` through the Bessel path: (θ_f part, θ̇_f part) sampled every ``dt``."""
    a1, a0 = bessel.coefficients()
    h = dt / FINE
    warm = int(20.0 / (bessel.w * h))  # twenty time constants
    w = math.sqrt(psd / h) * rng.standard_normal(n * FINE + warm)
    num_y, den = signal.cont2discrete(([a0], [1.0, a1, a0]), h, method="zoh")[:2]
    num_yd, den2 = signal.cont2discrete(([a0, 0.0], [1.0, a1, a0]), h, method="zoh")[:2]
    y = signal.lfilter(np.ravel(num_y), den, w)[warm::FINE][:n]
    yd = signal.lfilter(np.ravel(num_yd), den2, w)[warm::FINE][:n]
    return y, yd


def from_config(rig: RigConfig) -> NoiseModel:
    s = rig.sensors
    return NoiseModel(float(s.theta_noise), float(s.theta_dot_noise), 0.0, "config")


def _psd(x: np.ndarray, fs: float) -> tuple[np.ndarray, np.ndarray]:
    nper = min(len(x), 512)
    return signal.welch(x - np.mean(x), fs=fs, nperseg=nper, detrend="linear")


def _shapes(f: np.ndarray, fs: float, bessel: BesselPath | None) -> tuple[np.ndarray, np.ndarray]:
    """|H|² and |ω H|² as sampled at ``fs``: the broadband noise before the filter aliases into the band (the θ̇
    channel falls only as 1/ω), so each bin holds its images up to ALIASES × fs."""
    if bessel is None:
        return np.zeros_like(f), np.zeros_like(f)
    th, thd = np.zeros_like(f), np.zeros_like(f)
    for k in range(-ALIASES, ALIASES + 1):
        omega = 2 * np.pi * (f + k * fs)
        h2 = np.abs(bessel.response(omega)) ** 2
        th += h2
        thd += h2 * omega**2
    return th, thd


def estimate(prep: Prepared, rig: RigConfig) -> NoiseModel:
    """The recording's sensor noise (the module docstring); the config's where the data cannot speak."""
    prior = from_config(rig)
    s = rig.sensors
    fs = 1.0 / prep.dt
    hi = 0.45 * fs
    encoder_theta = s.theta_noise < 0.5 * s.theta_rad_per_count
    if encoder_theta or hi <= SPECTRUM_FROM or prep.n < 4 * 512:
        return prior
    f, p_th = _psd(prep.theta_f, fs)
    band = (f >= SPECTRUM_FROM) & (f <= hi)
    if band.sum() < MIN_BINS:
        return prior
    f, p_th = f[band], p_th[band]
    shape_th, shape_thd = _shapes(f, fs, prep.bessel)
    rows, target = [np.column_stack([np.ones_like(f), np.zeros_like(f), shape_th]) / p_th[:, None]], [np.ones_like(f)]
    if prep.theta_dot_f is not None:
        _, p_thd = _psd(prep.theta_dot_f, fs)
        p_thd = p_thd[band]
        rows.append(np.column_stack([np.zeros_like(f), np.ones_like(f), shape_thd]) / p_thd[:, None])
        target.append(np.ones_like(f))
    coef, _ = optimize.nnls(np.vstack(rows), np.concatenate(target))
    a_th, a_thd, b = (float(c) for c in coef)
    # one-sided white PSD a = 2 σ² dt; the Monte Carlo quantises itself, so its step²/12 is taken out
    th_adc = math.sqrt(max(a_th * fs / 2 - s.theta_rad_per_count**2 / 12, 0.0))
    thd_adc = (math.sqrt(max(a_thd * fs / 2 - s.theta_dot_rad_s_per_count**2 / 12, 0.0))
               if prep.theta_dot_f is not None else prior.theta_dot_adc)
    est = NoiseModel(th_adc, thd_adc, b / 2 if prep.bessel is not None else 0.0, "recording")
    return NoiseModel(est.theta_adc, est.theta_dot_adc, est.prefilter_psd, est.source, _note(est, prior, prep))


def _note(est: NoiseModel, prior: NoiseModel, prep: Prepared) -> str:
    data, conf = est.rms(prep.dt, prep.bessel), prior.rms(prep.dt, prep.bessel)
    parts = f"θ ADC {est.theta_adc:.3g} rad, θ̇ ADC {est.theta_dot_adc:.3g} rad/s"
    if est.prefilter_psd > 0:
        parts += f", before the filter {math.sqrt(est.prefilter_psd):.3g} rad/√Hz"
    line = f"sensor noise measured above {SPECTRUM_FROM:.0f} Hz: {parts} (θ rms {data:.3g} rad; config {conf:.3g} rad)"
    ratio = data / conf if conf > 0 else math.inf
    if not 1 / DISAGREE <= ratio <= DISAGREE:
        line += (f" — {ratio:.2g}× the config's: the noise floor uses the measured noise; check the config's "
                 "[sensors] noise or the wiring")
    return line
