"""Stage: effects too small to matter next to the recording's noise floor (furuta_rt.diagnose.judgement.practical)
are reported apart, and each equation refitted without them."""

from __future__ import annotations

from furuta_rt.diagnose.judgement import practical
from furuta_rt.diagnose.regression.library import Context
from furuta_rt.diagnose.regression.selection import EquationModel
from furuta_rt.diagnose.stages.findings import EquationResult, Found, found_in, refit
from furuta_rt.diagnose.stages.state import State


def stage(s: State) -> State:
    res = dict(s.res)  # split's working copy
    found, below = split(s.ctx, dict(s.ems), res, list(s.found), s.opts.seed)
    s = s.with_(res=res, found=found, below_practical=below)
    if below:
        s = s.noted(practical.describe(below))
    return s.forget(e["name"] for e in below)


def split(ctx: Context, ems: dict[str, EquationModel], res: dict[str, EquationResult], found: list[Found],
          seed: int) -> tuple[list[Found], list[dict]]:
    """(the effects of practical size, the others as {name, equation, params, size, floor}); ``res`` is refitted in
    place without the latter."""
    below: list[dict] = []
    for eq, r in list(res.items()):
        mine = [f for f in found if f.equation == eq and f.source == practical.ID]
        if not mine:
            continue
        names, share, floor = practical.too_small(ctx, ems[eq], r.selected, [f.name for f in mine], seed)
        small = [f for f in mine if f.name in names]
        if not small:
            continue
        spec = r.selected.spec
        for f in small:
            spec = spec.without(f.name)
        res[eq] = EquationResult(eq, r.rows, r.nominal, refit(ems[eq], spec) if spec.effects else r.nominal,
                                 r.trace, r.location)
        keep = {f.name for f in mine} - {f.name for f in small}
        fresh = {f.name: f for f in found_in(ems[eq], res[eq], []) if f.name in keep}
        found = [fresh.get(f.name, f) if f.equation == eq and f.source == practical.ID else f
                 for f in found if f not in small]
        below += [{"name": f.name, "equation": eq, "params": f.params, "size": share[f.name], "floor": floor}
                  for f in small]
    return found, below
