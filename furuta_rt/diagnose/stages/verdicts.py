"""Stage: each equation's verdict (furuta_rt.diagnose.judgement.verdict) — is what is left of its residual the
recording's noise, or a misfit the library's effects do not explain."""

from __future__ import annotations

from furuta_rt.diagnose.judgement import verdict
from furuta_rt.diagnose.stages.state import State


def stage(s: State) -> State:
    not_predictive = s.gated.not_predictive if s.gated is not None else []
    return s.with_(verdicts=verdict.assess(s.ctx, dict(s.ems), dict(s.res), s.opts.seed, list(s.found), not_predictive))
