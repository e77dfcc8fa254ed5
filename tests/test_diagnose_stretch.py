"""A log's balancing stretch (stages.start.balancing_span) and the closed-loop re-simulation: a stretch that starts after a
swing-up's catch — the pendulum and the arm moving, the arm turned away from zero — is not re-simulated from rest."""

from __future__ import annotations

import numpy as np

from furuta_rt.config import load_rig
from furuta_rt.diagnose.stages.closed_loop import moving_start, resimulation
from furuta_rt.diagnose.stages.findings import Options
from furuta_rt.diagnose.stages.start import balancing_span
from furuta_rt.recording import Recording


def log(n: int = 1000, catch: int = 400) -> Recording:
    """500 Hz: swinging up until ``catch`` (θ through π to 0, the arm turning), then balancing with the arm at −4.4 rad
    returning slowly."""
    t = np.arange(n) / 500.0
    theta = np.where(np.arange(n) < catch, np.pi * (1 - np.arange(n) / catch), 0.01 * np.sin(3 * t))
    theta[catch:catch + 20] = np.linspace(0.3, 0.0, 20)  # caught at 0.3 rad, still moving
    phi = np.where(np.arange(n) < catch, -4.4 * np.arange(n) / catch, -4.4 + 0.2 * (t - t[catch]))
    balancing = (np.arange(n) >= catch).astype(float)
    return Recording(t=t, theta=theta, phi=phi, u=np.zeros(n), theta_dot=None, extra={"balancing": balancing})


def test_a_stretch_after_a_catch_is_not_resimulated_from_rest() -> None:
    notes: list[str] = []
    stretch = balancing_span(log(), notes)
    assert len(stretch) == 600 and stretch.meta["stretch_of_log"]
    why = moving_start(stretch)
    assert "-4.40 rad" in why and "θ̇" in why
    stats, why_not = resimulation(stretch, load_rig("thesis"), [], Options())
    assert stats is None and "re-simulation starts from rest and is skipped" in why_not


def test_a_stretch_that_starts_at_rest_near_zero_is_not_refused() -> None:
    rec = log()
    rec.phi[:] = 0.001 * np.sin(np.arange(len(rec)) / 50.0)
    rec.theta[400:420] = 0.0
    stretch = balancing_span(rec, [])
    assert moving_start(stretch) == ""
