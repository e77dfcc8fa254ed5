"""Stage: the arm's starts from rest (furuta_rt.diagnose.stages.onset) time the actuator where the regression found no
latency; with a total latency they pin, the arm model is refitted at it with the latency among its effects."""

from __future__ import annotations

from furuta_rt.diagnose.regression.library import ARM
from furuta_rt.diagnose.stages import latency, onset
from furuta_rt.diagnose.stages.findings import EquationResult
from furuta_rt.diagnose.stages.state import State


def stage(s: State) -> State:
    if any(f.name in latency.LATENCY_EFFECTS for f in s.found) or s.ems[ARM].n_rows < 20 * s.opts.thresholds.n_blocks:
        return s
    timing = onset.assess(s.rig, s.current, s.ctx.prep, s.ctx.fine)
    s = s.with_(starts=timing)
    if timing is None or timing.total is None:
        return s
    value = timing.total - s.ctx.prep.command_lag  # path.delay: on top of the config's lag
    name = latency.effect_for(value)
    r = s.res[ARM]
    ev = latency.refit_at(s.ems[ARM], r.selected.spec.with_effect(name), value, r.selected)
    ev.t_stat[name] = abs(value) / timing.se
    ev.se[name] = {"delay": timing.se}
    trace = [*r.trace, {"step": len(ev.spec.effects), "candidate": "latency (arm starts)", "accepted": True, "ok": True,
                        "t": ev.t_stat[name], "value": value, "params": timing.as_json(), "cv_gain": 0.0}]
    s = s.with_result(ARM, EquationResult(ARM, r.rows, r.nominal, ev, trace, r.location))
    return s.reread(ARM, new=latency.LATENCY_EFFECTS)
