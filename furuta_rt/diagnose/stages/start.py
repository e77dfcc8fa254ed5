"""The start of a diagnosis: the recording's balancing stretch, put on a grid with θ reconstructed
(furuta_rt.diagnose.regression.states), its conventions checked, and the regression's Context built at the kernel
widths the encoder allows — the State every stage reads (furuta_rt.diagnose.stages.state)."""

from __future__ import annotations

import numpy as np

from furuta_rt.config import RigConfig
from furuta_rt.diagnose.judgement import noise
from furuta_rt.diagnose.regression.library import Context
from furuta_rt.diagnose.regression.states import GaussianFilter, Prepared, prepare
from furuta_rt.diagnose.stages import conventions
from furuta_rt.diagnose.stages.findings import Options
from furuta_rt.diagnose.stages.state import State
from furuta_rt.recording import Recording


def start(rec: Recording, rig: RigConfig, opts: Options) -> State:
    """The State before the first stage: the prepared recording, its Context, and the notes on how it was read."""
    notes: list[str] = list(rec.meta.get("input_notes", []))  # what the reader converted (diagnose.sanity)
    rec = balancing_span(rec, notes)
    prep = prepare(rec, rig)
    notes += prep.notes + (conventions.conventions(prep, rig) if opts.check_conventions else [])
    ctx = Context.build(prep, rig, opts.sigma_arm or arm_sigma(prep), opts.sigma_pend, opts.sigma_fine,
                        frozenset(opts.also_search))
    if noise.sensor_noise(ctx).note:
        notes.append(noise.sensor_noise(ctx).note)
    return State(rec=rec, rig=rig, opts=opts, ctx=ctx, notes=tuple(notes))


def balancing_span(rec: Recording, notes: list[str]) -> Recording:
    """A log's longest stretch of balancing ticks (idle or tripped ticks follow other physics: the loop is
    open, the pendulum may hang or be held); the whole recording when it has no such column."""
    flag = rec.extra.get("balancing")
    if flag is None or bool(np.all(flag > 0.5)) or not bool(np.any(flag > 0.5)):
        return rec
    on = np.concatenate([[0], (flag > 0.5).astype(int), [0]])
    starts, stops = np.flatnonzero(np.diff(on) == 1), np.flatnonzero(np.diff(on) == -1)
    i = int(np.argmax(stops - starts))
    a, b = int(starts[i]), int(stops[i])
    notes.append(f"diagnosed the longest balancing stretch of the log, t = {rec.t[a]:.1f}–{rec.t[b - 1]:.1f} s")
    out = rec.slice(a, b)
    out.meta["stretch_of_log"] = True
    return out


ARM_SIGMAS = (0.03, 0.04, 0.05)
MAX_QUANTISATION_RATIO = 0.02


def arm_sigma(prep: Prepared) -> float:
    """The narrowest kernel that holds the encoder's quantisation noise in φ̈ below 2 % of the φ̈ signal.

    The arm residual's noise is that quantisation error times the inertia; it also leaks into the command
    (u feeds back φ), so where it is large it biases the input-side parameters (delay, gain). Wider
    kernels cut it as σ^−2.5 but blur the reversals, so the narrowest adequate one is used."""
    for sigma in ARM_SIGMAS:
        f = GaussianFilter.build(sigma, prep.dt)
        noise = prep.phi_lsb / np.sqrt(12.0) * float(np.linalg.norm(f.kernels[2]))
        signal = float(np.std(f.apply(prep.phi, 2)[prep.valid]))
        if signal > 0 and noise / signal <= MAX_QUANTISATION_RATIO:
            return sigma
    return ARM_SIGMAS[-1]
