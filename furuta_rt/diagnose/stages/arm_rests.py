"""Stage: the arm's rests against a torque (furuta_rt.diagnose.stages.armlock) — dry friction where the arm holds
against the pendulum's pull at zero command, the dead band's look-alike under small commands only. Needs no
regression rows: it assesses the arm where the regression has too few (a short recording at 50 Hz)."""

from __future__ import annotations

from furuta_rt.diagnose.stages import armlock
from furuta_rt.diagnose.stages.lookalikes import EXPERIMENTS
from furuta_rt.diagnose.stages.state import State


def stage(s: State) -> State:
    lock = armlock.assess(s.ctx.prep, s.rig)
    if lock is None:
        return s
    declared = armlock.declare(lock, [f.name for f in s.found], list(s.ctx.known),
                               EXPERIMENTS[frozenset({"arm_coulomb", "input_deadzone"})])
    return s.with_(arm_lock=lock, ambiguities=[*s.ambiguities, *declared]).noted(
        lock.text(), *armlock.above_sliding(lock, {f.name: f.params for f in s.found}))
