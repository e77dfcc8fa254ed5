"""Stage: a command of one magnitude cannot tell an input gain from a dead band.

The actuator's dead band (furuta_rt.model.actuator.Actuator.shape) takes its width w off every |u| above it; on a
recording whose acting commands all have one magnitude |u| (square pulses, a single step height) that is the input
gain 1 − w/|u| — the same column of the arm equation, so no fit can prefer one. An input gain g < 1 named on such a
recording is declared with the dead band w = (1 − g)·|u| as its look-alike, and the experiment that separates them.
"""

from __future__ import annotations

import numpy as np

from furuta_rt.diagnose.stages.state import State

COMMAND_OFF = 0.01  # |u| under this share of the actuator's limit is no command
ONE_LEVEL = 0.02  # the acting commands are of one magnitude when within this share of their median ...
ONE_LEVEL_SHARE = 0.9  # ... on at least this share of them
EXPERIMENT = ("a command with two or more magnitudes (steps of several heights, a ramp or a sine): a gain scales each "
              "magnitude, a dead band takes the same width off each")


def stage(s: State) -> State:
    gain = next((f for f in s.found if f.name == "input_gain"), None)
    names = {f.name for f in s.found}
    if gain is None or "input_deadzone" in names or any(
            set(a["effects"]) == {"input_gain", "input_deadzone"} for a in s.ambiguities):
        return s
    prep = s.ctx.prep
    u = np.abs(prep.u[prep.valid])
    u = u[u > COMMAND_OFF * s.rig.actuator.limit]
    if len(u) == 0:
        return s
    level = float(np.median(u))
    if float(np.mean(np.abs(u - level) <= ONE_LEVEL * level)) < ONE_LEVEL_SHARE:
        return s
    g = gain.params["gain"] / s.ctx.known_gain  # the departure from the nominal model's gain
    if g >= 1.0:  # a dead band only takes torque away
        return s
    width = (1.0 - g) * level
    entry = {
        "effects": ["input_gain", "input_deadzone"], "reported": "input_gain",
        "alternative": {"name": "input_deadzone", "params": {"width": width}},
        "reason": (f"the commands that act all have one magnitude ({level:.3g}): an input gain of {g:.3g} × the nominal "
                   f"and a dead band {width:.3g} wide (command units) give the same torque there"),
        "experiment": EXPERIMENT,
    }
    return s.with_(ambiguities=(*s.ambiguities, entry))
