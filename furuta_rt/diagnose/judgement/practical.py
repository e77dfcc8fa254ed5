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
    from furuta_rt.diagnose.regression.selection import EquationModel
    from furuta_rt.diagnose.stages.findings import EquationResult, Found

PRACTICAL_SHARE = 1e-3  # of the equation's torque scale
FLOOR_FRACTION = 0.1  # of the equation's noise floor (rms)
ID = "inverse dynamics"


def sizes(ctx: Context, em: EquationModel, r: EquationResult) -> dict[str, float]:
    """Each selected effect's torque rms on the equation's rows, relative to its torque scale."""
    spec, coef = r.selected.spec, r.selected.fit.coef
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


def split(ctx: Context, ems: dict[str, EquationModel], res: dict[str, EquationResult], found: list[Found],
          seed: int) -> tuple[list[Found], list[dict]]:
    """(the effects of practical size, the others as {name, equation, params, size, floor}); ``res`` is refitted in
    place without the latter."""
    from furuta_rt.diagnose.stages.findings import EquationResult, found_in, refit

    below: list[dict] = []
    for eq, r in list(res.items()):
        if not any(f.equation == eq and f.source == ID for f in found):
            continue
        share = sizes(ctx, ems[eq], r)
        floor = floor_share(ctx, ems[eq], seed)
        small = [f for f in found if f.equation == eq and f.source == ID and f.name in share
                 and share[f.name] < max(PRACTICAL_SHARE, FLOOR_FRACTION * floor)]
        if not small:
            continue
        spec = r.selected.spec
        for f in small:
            spec = spec.without(f.name)
        res[eq] = EquationResult(eq, r.rows, r.nominal, refit(ems[eq], spec) if spec.effects else r.nominal,
                                 r.trace, r.location)
        keep = {f.name for f in found if f.equation == eq and f.source == ID} - {f.name for f in small}
        fresh = {f.name: f for f in found_in(ems[eq], res[eq], []) if f.name in keep}
        found = [fresh.get(f.name, f) if f.equation == eq and f.source == ID else f for f in found if f not in small]
        below += [{"name": f.name, "equation": eq, "params": f.params, "size": share[f.name], "floor": floor}
                  for f in small]
    return found, below


def describe(below: list[dict]) -> str:
    """One line for the report."""
    return "below practical size (not reported as effects): " + "; ".join(
        f"{b['name']} " + ", ".join(f"{k}={v:.3g}" for k, v in b["params"].items())
        + f" ({b['size']:.2%} of the {b['equation']} torque scale, floor {b['floor']:.2%})" for b in below)
