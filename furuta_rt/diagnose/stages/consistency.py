"""Stage: the found effects checked as one set of the effects vocabulary (furuta_rt.model.effects); a combination it
forbids is reported as found but cannot be simulated."""

from __future__ import annotations

from furuta_rt.diagnose.stages.findings import effects_of
from furuta_rt.diagnose.stages.state import State


def stage(s: State) -> State:
    try:
        effects_of(list(s.found))
    except ValueError as err:
        return s.noted(f"the found effects are not a consistent set ({err}); reported as found, not simulated")
    return s
