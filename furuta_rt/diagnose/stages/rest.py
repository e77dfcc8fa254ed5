"""A rest at zero command tells a constant arm torque (arm_bias) from what acts only with motion or command.

On one constant voltage step the arm equation's rows see the same column three times: the extra torque of an input
gain (g − 1)·K·V, a constant torque τ and a sliding Coulomb level −Fc (all constant while the arm turns one way).
The rows where the arm rests before the step (u = 0) are outside the regression (a rest is not eq. 4's business
when friction may hold it), yet they separate them: an input gain and Coulomb friction exert nothing there, a bias
τ keeps pushing — it is held only by a dry friction whose stick limit is at least |τ|. Without such friction in the
model, a bias that would have turned the arm by many encoder counts over the rest is contradicted by it.
"""

from __future__ import annotations

import numpy as np

from furuta_rt.diagnose.regression.library import STILL_TICKS, Context
from furuta_rt.diagnose.regression.selection import Evaluation

REST_Z = 4.0  # the bias beyond the model's stick limit, in its standard errors
REST_COUNTS = 10.0  # ... and the turn it would give over the longest rest, in encoder counts


def stick_limit(ctx: Context, params: dict[str, dict[str, float]]) -> float:
    """The largest torque the model's dry friction holds at rest (arm_stiction Fs, arm_lugre Fs, arm_coulomb Fc;
    the fitted value, else the rig's own)."""
    out = 0.0
    for name, key in (("arm_coulomb", "Fc"), ("arm_stiction", "Fs"), ("arm_lugre", "Fs")):
        value = params.get(name, {}).get(key, ctx.known_value(name, key))
        out = max(out, float(value))
    return out


def longest_rest(ctx: Context) -> tuple[int, int] | None:
    """[start, stop) of the longest stretch with the arm at one encoder count and no command acting (the commands of
    the last command_lag as well); None when there is none of ≥ STILL_TICKS. The encoder counts need no derivative:
    the kernels' edges (outside Prepared.valid) count too, and a rest before an early step often lies there."""
    prep = ctx.prep
    lag = round(prep.command_lag / prep.dt) + 1
    acting = np.convolve((prep.u != 0).astype(float), np.ones(lag + 1), mode="full")[: prep.n] > 0
    cnt = np.round(prep.phi / prep.phi_lsb).astype(np.int64)
    same = np.concatenate([[False], np.diff(cnt) == 0])
    ok = ~acting & (same | np.roll(same, -1))
    edges = np.flatnonzero(np.diff(np.concatenate([[0], ok.astype(int), [0]])))
    if len(edges) == 0:
        return None
    starts, stops = edges[::2], edges[1::2]
    i = int(np.argmax(stops - starts))
    if stops[i] - starts[i] < STILL_TICKS:
        return None
    return int(starts[i]), int(stops[i])


def bias_at_rest(ctx: Context, bias_model: Evaluation) -> dict | None:
    """Whether the arm's rest at zero command contradicts the arm_bias of ``bias_model``: its τ beyond the model's stick
    limit by ≥ REST_Z standard errors, and enough to turn the free arm by ≥ REST_COUNTS counts over the rest. None when
    the model has no bias or the recording no rest; else {contradicts, tau, limit, rest_s, turn_rad, text}."""
    tau = bias_model.params.get("arm_bias", {}).get("tau")
    rest = longest_rest(ctx)
    if tau is None or rest is None:
        return None
    se = float(bias_model.se.get("arm_bias", {}).get("tau", 0.0))
    limit = stick_limit(ctx, bias_model.params)
    excess = abs(tau) - limit
    T = (rest[1] - rest[0]) * ctx.prep.dt
    J = ctx.base_inertia + bias_model.spec.d_inertia
    turn = max(excess, 0.0) * T**2 / (2.0 * J)
    contradicts = excess > REST_Z * se and turn >= REST_COUNTS * ctx.prep.phi_lsb
    t0 = float(ctx.prep.t[rest[0]])
    text = (f"the arm rests {T:.2f} s at zero command (from t = {t0:.2f} s) without moving; a constant torque of "
            f"{tau:+.3g} N m, {'beyond' if excess > 0 else 'within'} the model's stick limit {limit:.3g} N m, "
            + (f"would have turned it by {turn:.3g} rad there" if excess > 0 else "could be held by its friction"))
    return {"contradicts": bool(contradicts), "tau": float(tau), "limit": limit, "rest_s": T, "turn_rad": turn,
            "text": text}
