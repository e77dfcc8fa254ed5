"""Stage: effects too small to matter next to the recording's noise floor (furuta_rt.diagnose.judgement.practical)
are reported apart, and each equation refitted without them."""

from __future__ import annotations

from furuta_rt.diagnose.judgement import practical
from furuta_rt.diagnose.stages.state import State


def stage(s: State) -> State:
    res = dict(s.res)  # practical.split's working copy
    found, below = practical.split(s.ctx, dict(s.ems), res, list(s.found), s.opts.seed)
    s = s.with_(res=res, found=found, below_practical=below)
    if below:
        s = s.noted(practical.describe(below))
    return s.forget(e["name"] for e in below)
