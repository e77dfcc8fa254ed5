"""Stage: a command of one magnitude cannot tell an input gain from a dead band.

The actuator's dead band (furuta_rt.model.actuator.Actuator.shape) takes its width w off every |u| above it; on a
recording whose acting commands all have one magnitude |u| (square pulses, a single step height) that is the input
gain 1 − w/|u| — the same column of the arm equation, so no fit can prefer one. An input gain g < 1 named on such a
recording is declared with the dead band w = (1 − g)·|u| as its look-alike, and the experiment that separates them.

Dry friction's sliding level does the same when, besides, the arm slides one way only under that command (a single
voltage step): Fc·sgn(φ̇) is then a constant torque against K·g·u on every moving row, so the gain read is
g − Fc/(K·|u|) and no Fc can be read beside it (the rest before the step has no pull to bound it). The notes say so
and name the recordings that separate them: steps of other heights, fitted jointly (`diagnose a.csv b.csv`), where
K·g·u − Fc changes with u.
"""

from __future__ import annotations

import numpy as np

from furuta_rt.diagnose.stages.state import State

COMMAND_OFF = 0.01  # |u| under this share of the actuator's limit is no command
ONE_LEVEL = 0.02  # the acting commands are of one magnitude when within this share of their median ...
ONE_LEVEL_SHARE = 0.9  # ... on at least this share of them
SLIDING_COUNTS_S = 20.0  # the arm slides where |φ̇| exceeds this many encoder counts per second
ONE_WAY_SHARE = 0.98  # ... one way only when this share of its sliding rows under the command has one sign
EXPERIMENT = ("a command with two or more magnitudes (steps of several heights, a ramp or a sine): a gain scales each "
              "magnitude, a dead band takes the same width off each")


def stage(s: State) -> State:
    gain = next((f for f in s.found if f.name == "input_gain"), None)
    if gain is None:
        return s
    prep = s.ctx.prep
    acting = prep.valid & (np.abs(prep.u) > COMMAND_OFF * s.rig.actuator.limit)
    u = np.abs(prep.u[acting])
    if len(u) == 0:
        return s
    level = float(np.median(u))
    if float(np.mean(np.abs(u - level) <= ONE_LEVEL * level)) < ONE_LEVEL_SHARE:
        return s
    s = _sliding_friction(s, acting, level)
    return _dead_band(s, gain.params["gain"] / s.ctx.known_gain, level)


def _sliding_friction(s: State, acting: np.ndarray, level: float) -> State:
    """The note where the arm slid one way only under the one command magnitude and no dry friction was named."""
    if {f.name for f in s.found} & {"arm_coulomb", "arm_stiction", "arm_lugre"}:
        return s
    prep = s.ctx.prep
    phi_dot = np.gradient(prep.phi, prep.dt)[acting]
    sliding = phi_dot[np.abs(phi_dot) > SLIDING_COUNTS_S * prep.phi_lsb]
    if len(sliding) == 0 or max(np.mean(sliding > 0), np.mean(sliding < 0)) < ONE_WAY_SHARE:
        return s
    return s.noted(
        f"dry friction cannot be read on this recording: the arm slid one way only under one command magnitude "
        f"({level:.3g}), where a sliding friction Fc is the same torque as part of the input gain (the gain read is "
        f"g − Fc/(K·{level:.3g})); steps of other heights fitted together with this one (diagnose a.csv b.csv) "
        f"separate them")


def _dead_band(s: State, g: float, level: float) -> State:
    """The dead band's look-alike of an input gain g < 1 (× the nominal) on one command magnitude."""
    if "input_deadzone" in {f.name for f in s.found} or any(
            set(a["effects"]) == {"input_gain", "input_deadzone"} for a in s.ambiguities):
        return s
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
