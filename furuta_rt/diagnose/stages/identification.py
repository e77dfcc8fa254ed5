"""Stage: the arm's jointly calibrated parameters and the combinations the data pins
(furuta_rt.diagnose.regression.identify); each inverse-dynamics effect marked pinned alone or only in a combination."""

from __future__ import annotations

from dataclasses import replace

from furuta_rt.diagnose.regression import identify
from furuta_rt.diagnose.regression.library import ARM
from furuta_rt.diagnose.stages.state import State


def stage(s: State) -> State:
    ident = identify.identification(s.ems[ARM], s.res[ARM].selected)
    found = []
    for f in s.found:
        if f.source == "inverse dynamics":
            pinned, combinations = identify.pinning(ident, f.name)
            f = replace(f, pinned=pinned, combinations=combinations)
        found.append(f)
    return s.with_(identification=ident, found=found)
