"""Stage: where the largest commands are out of the arm regression's reach, the arm's response to them
(furuta_rt.diagnose.stages.peaks) decides on an actuator torque limit."""

from __future__ import annotations

from furuta_rt.diagnose.regression.library import ARM, STILL_TICKS
from furuta_rt.diagnose.stages import peaks
from furuta_rt.diagnose.stages.equations import support
from furuta_rt.diagnose.stages.findings import Found
from furuta_rt.diagnose.stages.state import State


def stage(s: State) -> State:
    ctx, current = s.ctx, s.current
    if not s.opts.stick_windows or not ctx.prep.commanded or "input_saturation" in current \
            or peaks.covered(ctx.prep, s.ems[ARM].row_mask) >= peaks.MIN_COVERED:
        return s
    gain = current.get("input_gain", {}).get("gain", ctx.known_gain)
    arm, selected = s.ems[ARM], s.res[ARM].selected
    peak = peaks.assess(ctx.rig, current, ctx.prep, ctx.fine, s.opts.thresholds, ctx.stays(STILL_TICKS), ctx.fine.phi_dot,
                        lambda limit: support(arm, selected, s.opts, "limit", limit / gain))
    s = s.with_(peak=peak)
    if peak is None:
        return s
    return s.add(*(Found(name, ARM, params, {peak.fits[name].param: peak.fits[name].se}, peak.fits[name].t,
                         peak.fits[name].gain, "peak windows") for name, params in peak.added.items()))
