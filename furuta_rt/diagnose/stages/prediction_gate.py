"""Stage: the prediction gate (furuta_rt.diagnose.stages.gate) — an effect whose presence makes the multi-step
prediction of held-out windows significantly worse is moved out of the findings, and each equation refitted without
it."""

from __future__ import annotations

from furuta_rt.diagnose.stages import gate
from furuta_rt.diagnose.stages.state import State


def stage(s: State) -> State:
    res, notes = dict(s.res), list(s.notes)  # the gate's working copies
    gated = gate.run(s.ctx, dict(s.ems), res, list(s.found), s.opts, notes, s.stick, s.peak)
    s = s.with_(gated=gated, res=res, notes=notes, found=gated.found)
    return s.forget(e["name"] for e in gated.not_predictive)
