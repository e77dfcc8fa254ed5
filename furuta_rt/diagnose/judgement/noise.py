"""The noise floor of an inverse-dynamics residual: what the sensors alone put into it.

The residual of eq. 4 is computed from states reconstructed from the measurements (encoder counts of φ, the
θ channel through its ADC — and through the inverse Bessel path when the rig has one — every signal seen
through the equation's Gaussian kernel, furuta_rt.diagnose.regression.states). Even with the right model it is not
zero: the encoder's and the ADC's quantisation and the ADC noise, differentiated twice through the kernel,
reach it through the accelerations (α θ̈, γ cos θ φ̈, M22 φ̈ …).

Estimated by Monte Carlo on the recording itself: the measured signals are smoothed (the fine kernel), then
re-measured at the rig's sensor settings (RigConfig.sensors: encoder counts per revolution, θ and θ̇ ADC
resolutions; a random sub-count phase per draw) with the noise measured on the recording itself
(furuta_rt.diagnose.judgement.noise_model: ADC noise and noise entering before the Bessel filter), and each re-measured copy goes
through the same kernel, the same Bessel reconstruction and FurutaPlant.inverse_dynamics. The difference of
the residual between a re-measured copy and the smoothed one is one draw of the sensor part of the residual,
on the recording's own motion (where the arm is slow the encoder's error is a ramp, where it is fast it is
white — both as in the recording). To each draw is added the processing error: the kernel's own bias in the
nonlinear eq. 4 (``processing``), the same in every draw, so the floor holds everything but the physics.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from scipy.interpolate import make_interp_spline

from furuta_rt.diagnose.judgement import noise_model
from furuta_rt.diagnose.regression.library import ARM, Context
from furuta_rt.diagnose.regression.states import GaussianFilter, Prepared, States
from furuta_rt.model.sensors import quantise as _quantise

DRAWS = 4  # Monte Carlo draws of the sensor noise
CLEAN_SIGMA = 0.02  # s, kernel of the smoothed ("noise-free") θ channel that is re-measured
PROCESSING_SIGMA = 0.005  # s, the nearly unsmoothed states the kernel's bias is measured against
PROCESSING_SAMPLES = 2.5  # ... on a grid at least this many steps per PROCESSING_SIGMA (the recording's, or finer)


def remeasured(prep: Prepared, ctx: Context, rng: np.random.Generator, clean: Prepared) -> Prepared:
    """A copy of ``clean`` measured again by the rig's sensors (RigConfig.sensors)."""
    s = ctx.rig.sensors
    phi = _quantise(clean.phi, prep.phi_lsb, rng.uniform(-0.5, 0.5))
    n_th, n_thd = sensor_noise(ctx).sample(prep.n, prep.dt, prep.bessel, rng, clean.theta_dot_f is not None)
    theta = _quantise(clean.theta_f + n_th, s.theta_rad_per_count, rng.uniform(-0.5, 0.5))
    theta_dot = None
    if clean.theta_dot_f is not None:
        theta_dot = _quantise(clean.theta_dot_f + n_thd, s.theta_dot_rad_s_per_count, rng.uniform(-0.5, 0.5))
    return replace(prep, theta_f=theta, theta_dot_f=theta_dot, phi=phi)


def sensor_noise(ctx: Context) -> noise_model.NoiseModel:
    """The recording's sensor noise (noise_model.estimate), computed once per Context."""
    key = "sensor noise model"
    if key not in ctx._columns:
        ctx._columns[key] = noise_model.estimate(ctx.prep, ctx.rig)  # type: ignore[assignment]
    return ctx._columns[key]  # type: ignore[return-value]


def through_edges(t: np.ndarray, x: np.ndarray, step: float) -> np.ndarray:
    """A quantised signal's continuous estimate: where the count changes, the signal crossed the level between the
    two counts (half-way between the samples), so the estimate passes through those crossings and is linear between
    them. Unlike any smoothing, it keeps the crossing times, hence the error structure of slow motion (a ramp and a
    step per count) in the re-quantised copies."""
    c = np.round(x / step)
    idx = np.flatnonzero(np.diff(c))
    if len(idx) < 2:
        return x.astype(float)
    tt = 0.5 * (t[idx] + t[idx + 1])
    return np.interp(t, tt, 0.5 * (c[idx] + c[idx + 1]) * step)


def smoothed(prep: Prepared, ctx: Context, sigma: float = CLEAN_SIGMA) -> Prepared:
    """A stand-in for the noise-free measurement: the encoder's φ through its count crossings; the θ channel through
    a kernel of width ``sigma`` (its ADC noise dithers the quantisation) or, without noise (an encoder), through its
    count crossings too."""
    f = GaussianFilter.build(sigma, prep.dt)
    s = ctx.rig.sensors
    if s.theta_noise < 0.5 * s.theta_rad_per_count:
        theta = _edge_safe(f, through_edges(prep.t, prep.theta_f, s.theta_rad_per_count))
    else:
        theta = _edge_safe(f, prep.theta_f)
    theta_dot = None if prep.theta_dot_f is None else _edge_safe(f, prep.theta_dot_f)
    return replace(prep, theta_f=theta, theta_dot_f=theta_dot, phi=_edge_safe(f, through_edges(prep.t, prep.phi, prep.phi_lsb)))


def finer(prep: Prepared, m: int) -> Prepared:
    """``prep`` on a grid m times finer: the (smoothed) signals through quintic splines, whose second derivative
    errs by O((ω·dt)⁴) — the reference the grid's (ω·dt)² kernel differences are measured against; the command
    held."""
    if m == 1:
        return prep
    t = prep.t[0] + np.arange((prep.n - 1) * m + 1) * (prep.dt / m)

    def up(x: np.ndarray) -> np.ndarray:
        return make_interp_spline(prep.t, x, k=5)(t)

    hold = np.minimum(np.arange(len(t)) // m, prep.n - 1)
    return replace(prep, t=t, dt=prep.dt / m, theta_f=up(prep.theta_f), phi=up(prep.phi), u=prep.u[hold],
                   valid=prep.valid[hold], extra={},
                   theta_dot_f=None if prep.theta_dot_f is None else up(prep.theta_dot_f))


def _residual_as_selected(ctx: Context, equation: str, clean: Prepared, sigma: float, sigma_fine: float) -> np.ndarray:
    """The equation's state part of the residual on ``clean`` along the selection's path (Context.inverse_dynamics,
    plus the back-EMF damping of a voltage-driven arm)."""
    fine = clean.states(sigma_fine)
    s = clean.states(sigma, fine)
    c = replace(ctx, prep=clean, fine=fine, **{"arm" if equation == ARM else "pend": s}, _held={}, _tau0={}, _columns={})
    out = c.inverse_dynamics(equation)
    return out + ctx.back_emf * s.phi_dot if equation == ARM else out


def _edge_safe(f: GaussianFilter, x: np.ndarray) -> np.ndarray:
    y = f.apply(x, 0)
    h = f.half
    y[:h], y[-h:] = x[:h], x[-h:]
    return y


def _residual(ctx: Context, equation: str, s: States) -> np.ndarray:
    """The state-dependent part of the equation's residual (the command is measured exactly): ID of eq. 4, plus the
    back-EMF damping of a voltage-driven arm."""
    tp, ta = ctx.plant.inverse_dynamics(s.theta - ctx.model.theta_offset, s.theta_dot, s.phi_dot, s.theta_ddot,
                                        s.phi_ddot)
    return ta + ctx.back_emf * s.phi_dot if equation == ARM else tp


def draws(ctx: Context, equation: str, n_draws: int = DRAWS, seed: int = 0, clean_sigma: float = CLEAN_SIGMA) -> np.ndarray:
    """(n_draws, n) draws of the sensor part of ``equation``'s residual on the recording's grid (kept in the
    Context's cache: the prediction gate and the verdict both use them)."""
    key = f"noise floor {equation} {n_draws} {seed} {clean_sigma}"
    if key not in ctx._columns:
        ctx._columns[key] = _draws(ctx, equation, n_draws, seed, clean_sigma)
    return ctx._columns[key]


def _draws(ctx: Context, equation: str, n_draws: int, seed: int, clean_sigma: float) -> np.ndarray:
    prep = ctx.prep
    sigma = ctx.states(equation).filt.sigma
    clean = smoothed(prep, ctx, clean_sigma)
    base = _residual(ctx, equation, clean.states(sigma))
    rng = np.random.default_rng(seed)
    sensor = np.array([_residual(ctx, equation, remeasured(prep, ctx, rng, clean).states(sigma)) - base
                       for _ in range(n_draws)])
    return sensor + processing(ctx, equation, clean, base)


def processing(ctx: Context, equation: str, clean: Prepared, base: np.ndarray) -> np.ndarray:
    """The kernel's own bias in the residual (the processing error): eq. 4 is nonlinear in the states, so the
    residual of the kernel-smoothed states, ``base``, differs from the kernel-smoothed residual of the (nearly)
    unsmoothed ones by what the kernel does to cos θ·φ̈, sin θ·φ̇² … — largest at command steps and on large
    motions, and the same in every draw.

    It also holds the grid's own part: the kernel sees θ through the sampled Gaussian, θ̇ through it and the central
    difference's box, θ̈ and φ̈ through it and the second difference's triangle (GaussianFilter), three kernels that
    differ by about (ω·dt)²/12 on a motion at ω: on a 10 rad/s swing at 50 Hz a residual that follows θ like a 3 %
    error of the pendulum's inertia J2. The sharp reference is therefore taken on a grid fine enough for
    its own kernel (``finer``), where that part vanishes; at the rates whose step is under PROCESSING_SIGMA /
    PROCESSING_SAMPLES the grid is the recording's.

    The error is that of the path the equation's residual takes (Context.inverse_dynamics: eq. 4 on the lightly
    smoothed states F, then the kernel K, with F's curvature correction), not of eq. 4 on the wide states K∘F: on a
    swing-up the latter's bias is tens of % of the torque scale, a bias the residual does not carry."""
    s = ctx.states(equation)
    f = s.filt
    if s.fine is not None and s.outer is not None:  # the residual's own path: K * ID(F's states), curvature-corrected
        base = _residual_as_selected(ctx, equation, clean, s.outer.sigma, s.fine.filt.sigma)
    m = max(1, math.ceil(PROCESSING_SAMPLES * clean.dt / PROCESSING_SIGMA - 1e-6))
    sharp = _residual(ctx, equation, finer(clean, m).states(PROCESSING_SIGMA))[::m]
    out = base - GaussianFilter.build(f.sigma, clean.dt).apply(sharp, 0)
    h = f.half + GaussianFilter.build(PROCESSING_SIGMA, clean.dt).half + (3 if m > 1 else 0)  # + the splines' ends
    out[:h], out[-h:] = 0.0, 0.0  # the kernels' edges (outside the usable rows anyway)
    return out
