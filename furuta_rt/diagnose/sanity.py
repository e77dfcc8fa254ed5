"""Checks of a recording's units before it is diagnosed: what a wrong unit looks like, and the fix.

A pendulum recording is sampled at 10 Hz – 10 kHz. A time column whose median step is 0.5–100 is therefore in
milliseconds (a 1–200 Hz recording), one whose step is 100 or more in microseconds; either is converted to seconds
with a note rather than diagnosed as a recording of hours (which fits an arm length 10⁵ × the config's).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from furuta_rt.recording import Recording

MS_FROM, US_FROM = 0.5, 100.0  # median time step at and above which t is read as ms, µs


def time_in_seconds(rec: Recording) -> tuple[Recording, str | None]:
    """``rec`` with its time column in seconds, and a note when it was converted."""
    if len(rec.t) < 3:
        return rec, None
    step = float(np.median(np.diff(rec.t)))
    if step < MS_FROM:
        return rec, None
    unit, scale = ("µs", 1e-6) if step >= US_FROM else ("ms", 1e-3)
    note = (f"the time column steps {step:g} per sample: read as {unit} and converted to seconds "
            f"({1 / (step * scale):.0f} Hz); write t in seconds to silence this")
    return dataclasses.replace(rec, t=rec.t * scale), note
