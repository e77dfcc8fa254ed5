"""The practical-size rule: an effect is reported only when it matters.

An inverse-dynamics effect's size is the rms of the torque it adds to its equation (its column times its fitted
coefficient, on the equation's usable rows), relative to the equation's torque scale (locate.torque_scale; the
verdict's units). It is reported when that torque is at least PRACTICAL_SHARE of the torque scale *and* at least
FLOOR_FRACTION of its equation's noise floor (rms). Below the first, no user would rebuild a rig, retune a controller
or change a config for it (a pendulum viscous 1e-5 N m s on a noise-free recording, an input gain 0.9998). Below the
second, it changes the residual's rms by a²/2f ≈ 0.5 % of the floor f — less than the spread of the floor's own
Monte Carlo draws: no prediction the recording can check moves by more than its noise already does. Such effects
go to the "below practical size" list with their size; the equation is refitted without them, so the verdict
judges what is reported. Effects from other stages (free decay, stick and peak windows) are judged by their own stage and kept.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from furuta_rt.diagnose.judgement import noise
from furuta_rt.diagnose.judgement.locate import torque_scale

if TYPE_CHECKING:
    from furuta_rt.diagnose.regression.library import Context
    from furuta_rt.diagnose.regression.selection import EquationModel, Evaluation

PRACTICAL_SHARE = 1e-3  # of the equation's torque scale
FLOOR_FRACTION = 0.1  # of the equation's noise floor (rms)
ID = "inverse dynamics"


def sizes(ctx: Context, em: EquationModel, selected: Evaluation) -> dict[str, float]:
    """Each effect of ``selected``'s torque rms on the equation's rows, relative to its torque scale."""
    spec, coef = selected.spec, selected.fit.coef
    if not spec.effects or coef is None:
        return {}
    X, owners = em.design(spec)
    rows = em.row_mask
    scale = torque_scale(ctx, em.equation, rows)
    out: dict[str, float] = {}
    for name, sl in owners:
        if name in spec.effects:
            torque = X[:, sl] @ np.asarray(coef)[sl]
            out[name] = float(np.sqrt(np.mean(torque[rows] ** 2))) / scale
    return out


def floor_share(ctx: Context, em: EquationModel, seed: int) -> float:
    rows = em.row_mask
    draws = noise.draws(ctx, em.equation, seed=seed)[:, rows]
    return float(np.sqrt(np.mean(draws**2))) / torque_scale(ctx, em.equation, rows)


def too_small(ctx: Context, em: EquationModel, selected: Evaluation, names: list[str],
              seed: int) -> tuple[list[str], dict[str, float], float]:
    """(those of ``names`` below practical size in ``selected``, every selected effect's size, the equation's noise
    floor), sizes and floor as shares of the equation's torque scale."""
    share = sizes(ctx, em, selected)
    floor = floor_share(ctx, em, seed)
    return [n for n in names if n in share and share[n] < max(PRACTICAL_SHARE, FLOOR_FRACTION * floor)], share, floor


def describe(below: list[dict]) -> str:
    """One line for the report."""
    return "below practical size (not reported as effects): " + "; ".join(
        f"{b['name']} " + ", ".join(f"{k}={v:.3g}" for k, v in b["params"].items())
        + f" ({b['size']:.2%} of the {b['equation']} torque scale, floor {b['floor']:.2%})" for b in below)
