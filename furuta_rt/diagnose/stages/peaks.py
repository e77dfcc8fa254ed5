"""Command peaks: an actuator limit shows where the largest commands are, in how the arm moves after them.

The arm regression leaves out the rows whose filter window holds a stay at one encoder count (a stick, or
motion too slow for the encoder), and the largest commands often come straight out of such a stay: a step
of the reference with the arm at rest. A torque limit that clips only those commands can then hide from the
regression, while the arm's motion after them shows it plainly (clipped, the arm accelerates less).

Windows start PEAK_LEAD before each episode of large commands (|u| at or above its PEAK_QUANTILE), the arm's
starting velocity fitted to that lead-in, and run PEAK_TAIL past it. The arm is simulated as in the stick
windows (furuta_rt.diagnose.stages.stickslip: the shared Simulator with the recorded commands, the pendulum
teacher-forced, the error outside the measured encoder cells). The limit is chosen on a grid of the command's
own levels by blocked cross-validation over the windows and accepted by the regression's rules, its
significance judged by the blocks' paired improvement (a limit has no "departure" to test). Run only when the
regression did not see most of the peaks, and judged only when the model without a limit leaves the encoder's
cells by more than a count rms over the windows (``visible_error``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np

from furuta_rt.config import RigConfig
from furuta_rt.diagnose.regression.selection import Thresholds
from furuta_rt.diagnose.regression.states import Prepared, States
from furuta_rt.diagnose.stages.stickslip import Window, WindowStage, profile, window_errors
from furuta_rt.model.effects import Effects

PEAK_QUANTILE = 0.99
EPISODE_GAP = 0.1  # s: large commands closer than this are one episode
PEAK_LEAD = 0.1  # s before an episode: the lead-in that fixes the arm's starting velocity
VELOCITY_OFFSETS = np.array([-0.12, -0.06, -0.03, -0.015, 0.0, 0.015, 0.03, 0.06, 0.12])  # rad/s, tried on the lead-in
PEAK_TAIL = 0.25  # s after it
MAX_PEAK_SECONDS = 0.6
MAX_PEAK_WINDOWS = 16
MIN_PEAK_WINDOWS = 5
MIN_COVERED = 0.5  # the regression saw the peaks when this share of their ticks lies in its rows
LIMIT_QUANTILES = (0.9, 0.95, 0.98, 0.99, 0.995, 0.998)
LIMIT_FRACTIONS = (0.3, 0.5, 0.7, 0.85)  # of the largest |command|


def peak_ticks(prep: Prepared) -> np.ndarray:
    u = np.abs(prep.u)
    level = float(np.quantile(u[prep.valid], PEAK_QUANTILE))
    return prep.valid & (u >= level) & (u > 0)


def windows(prep: Prepared, stays: np.ndarray, phi_dot: np.ndarray) -> list[Window]:
    """One window per episode of large commands (the MAX_PEAK_WINDOWS largest, in time order), starting PEAK_LEAD
    before it with φ̇ = 0 inside a stay at one count (``stays``) and ``phi_dot`` elsewhere (refined by
    ``settle_velocity``)."""
    idx = np.flatnonzero(peak_ticks(prep))
    if not len(idx):
        return []
    gap, lead, tail, most = (round(s / prep.dt) for s in (EPISODE_GAP, PEAK_LEAD, PEAK_TAIL, MAX_PEAK_SECONDS))
    breaks = np.flatnonzero(np.diff(idx) > gap)
    starts, stops = idx[np.concatenate([[0], breaks + 1])], idx[np.concatenate([breaks, [len(idx) - 1]])] + 1
    last = int(np.flatnonzero(prep.valid)[-1])
    out = []
    for a, b in zip(starts, stops, strict=True):
        k = int(a) - lead
        h = min(int(b) - k + tail, most + lead, last - k - 1)
        if k >= 0 and prep.valid[k] and h > int(b) - k:
            v = 0.0 if stays[k] else float(phi_dot[k])
            out.append((float(np.max(np.abs(prep.u[a:b]))), Window(k, h, int(b), phi_dot=v)))
    out.sort(key=lambda x: -x[0])
    return sorted((w for _, w in out[:MAX_PEAK_WINDOWS]), key=lambda w: w.start)


def settle_velocity(rig: RigConfig, effects: Effects, prep: Prepared, fine: States, wins: list[Window]) -> list[Window]:
    """The windows with the arm's starting velocity chosen to fit the lead-in (the PEAK_LEAD before the episode) under
    ``effects``: the encoder does not resolve a slowly creeping arm, and with dry friction an error in its velocity
    persists. The limit under test clips only the episode, so one choice serves every model compared."""
    lead = round(PEAK_LEAD / prep.dt)
    out = []
    for w in wins:
        trial = [replace(w, horizon=lead, phi_dot=w.phi_dot + dv) for dv in VELOCITY_OFFSETS]
        err = window_errors(rig, effects, prep, fine, trial)
        best = int(np.argmin(err + 1e-12 * np.abs(VELOCITY_OFFSETS)))  # ties: the smallest change
        out.append(replace(w, phi_dot=trial[best].phi_dot))
    return out


def covered(prep: Prepared, rows: np.ndarray) -> float:
    """Share of the large-command ticks that lie in the arm regression's rows."""
    peaks = peak_ticks(prep)
    return float(np.sum(peaks & rows) / max(np.sum(peaks), 1))


def assess(rig: RigConfig, found: dict[str, dict[str, float]], prep: Prepared, fine: States, th: Thresholds,
           stays: np.ndarray, phi_dot: np.ndarray, support: Callable[[float], float | None]) -> WindowStage | None:
    """input_saturation on the peak windows, on top of the effects ``found`` (None when there are too few peaks).

    ``support(limit)``: the arm regression's held-out gain with that limit. The rows it has (sliding, away from
    stays) must not contradict the limit: a limit below commands the arm is seen to follow there is no limit."""
    wins = windows(prep, stays, phi_dot)
    if len(wins) < MIN_PEAK_WINDOWS or "input_saturation" in found:
        return None
    gain = found.get("input_gain", {}).get("gain", 1.0)
    top = gain * float(np.max(np.abs(prep.u[prep.valid])))
    u = gain * np.abs(prep.u[prep.valid])
    grid = sorted({*(float(np.quantile(u, q)) for q in LIMIT_QUANTILES), *(f * top for f in LIMIT_FRACTIONS)})
    grid = [v for v in grid if v > 0 and _allowed(support(v), th)]
    if not grid:  # every limit below the largest command contradicts the regression: nothing to simulate
        return None
    grid.append(1.01 * top)  # the last one clips nothing: the model without a limit
    wins = settle_velocity(rig, Effects.model_validate(found), prep, fine, wins)
    out = WindowStage(wins)

    def errors(limit: float) -> np.ndarray:
        eff = {**found, "input_saturation": {"limit": limit}} if limit < top else found
        return window_errors(rig, Effects.model_validate(eff), prep, fine, wins)

    base = errors(grid[-1])
    if float(np.sum(base)) < visible_error(prep, wins):  # the arm follows the peaks to within a count
        return out
    f = profile("input_saturation", "limit", errors, grid, grid[-1], base, th.n_blocks)
    f.paired = True
    f.support = support(f.value)
    ok = f.accepted(th) and f.value < top and _allowed(f.support, th)
    out.tried.append({"step": 0, **f.as_json(), "accepted": ok})
    if ok:
        out.added["input_saturation"] = {"limit": f.value}
        out.fits["input_saturation"] = f
    return out


def visible_error(prep: Prepared, wins: list[Window]) -> float:
    """The windows' error (``window_errors``' units, rad²) of a model that leaves the measured encoder cells by one
    count rms on every tick: below it the arm follows the peaks as the model predicts, to the encoder's resolution,
    and what a limit changes there is the teacher-forced simulation's own approximation (an independent simulator's
    noise-free null gained "−83 %" from a limit at 95 % of the largest command on errors of half a count)."""
    return sum(w.horizon for w in wins) * prep.phi_lsb**2


def _allowed(support: float | None, th: Thresholds) -> bool:
    """The regression's rows do not contradict a limit (they may not see it at all: no loss either way)."""
    return support is not None and support >= -th.min_gain


def describe(out: WindowStage) -> str:
    n = len(out.windows)
    if "input_saturation" not in out.fits:
        return f"command peaks: the arm follows the {n} largest commands as the model predicts"
    f = out.fits["input_saturation"]
    return (f"command peaks ({n} windows): the arm moves as if the torque were clipped at {f.value:.3g} N m "
            f"(held-out error −{100 * f.gain:.0f} %)")
