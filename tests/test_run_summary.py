"""The run summary's words match the run: no "try --comp coulomb" while a Coulomb compensation ran (chosen or from
--comp-from), and the first catch given in both time bases, saying what the swing-up's own time leaves out."""

from __future__ import annotations

import math

import numpy as np
import pytest

from furuta_rt.runtime.loop import LoopResult
from furuta_rt.runtime.summary import format_summary, summary_dict


def _limit_cycling() -> LoopResult:
    """A balancing run whose φ cycles ±0.4 rad every 2.5 s (section 4's friction limit cycle) and θ with it."""
    r = LoopResult(ticks=15000, balancing_ticks=15000, end="duration", host_span_s=30.0, device_span_s=30.0)
    for t in np.arange(0.0, 30.0, 0.002):
        theta, phi = 0.01 * math.sin(2 * math.pi * t / 2.5 + 1.0), 0.4 * math.sin(2 * math.pi * t / 2.5)
        r.trace.add(float(t), theta, phi)
        r.theta.add(theta)
        r.phi.add(phi)
    return r


@pytest.mark.parametrize(("mode", "advice"), [
    ("none", "try --comp coulomb"), ("coulomb", "with coulomb compensation active"),
    ("stiction", "with stiction compensation active"), ("adaptive", "with adaptive compensation active")])
def test_friction_advice_knows_the_compensation_that_ran(mode: str, advice: str) -> None:
    text = format_summary(_limit_cycling(), rate_hz=500, mode=mode, rig="thesis", log_path=None,
                          comp_source="diagnose report r.json: arm_coulomb Fc 0.3 N m" if mode == "coulomb" else "")
    line = next(line for line in text.splitlines() if "limit cycle: φ ±" in line)
    assert advice in line, line
    if mode != "none":
        assert "try --comp" not in text


def test_the_first_catch_says_its_time_base() -> None:
    r = LoopResult(ticks=5000, balancing_ticks=1000, swing_up_ticks=2000, catches=1,
                   first_catch_s=4.37, first_catch_run_s=5.37)
    text = format_summary(r, rate_hz=500, mode="none", rig="thesis", log_path=None)
    line = next(line for line in text.splitlines() if "swing-up:" in line)
    assert "first caught 4.37 s after the swing-up began (5.37 s into the run" in line and "not counted" in line
    su = summary_dict(r, rate_hz=500, mode="none", rig="thesis", log_path=None, warnings=[])["swing_up"]
    assert su["first_catch_s"] == 4.37 and su["first_catch_run_s"] == 5.37


def test_the_recent_trace_is_a_ring_that_keeps_nothing_per_tick() -> None:
    """The control loop stores t, θ, φ every balancing tick for the summary's limit cycles: the ring keeps the last
    ``capacity`` samples in time order, and storing holds on to no new object (a list of floats kept 72 bytes a
    tick: the control process grew until the ring wrapped)."""
    import tracemalloc

    from furuta_rt.runtime.trace import RecentTrace

    ring = RecentTrace(capacity=1000)
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        for k in range(2500):
            ring.add(k * 0.001, math.sin(k * 0.01), math.cos(k * 0.01))
        kept = tracemalloc.get_traced_memory()[0] - before
    finally:
        tracemalloc.stop()
    assert kept < 4096, f"{kept} bytes kept by 2500 stores"
    t, theta, phi = ring.arrays()
    k = np.arange(1500, 2500)
    assert np.array_equal(t, k * 0.001) and np.array_equal(theta, np.sin(k * 0.01)) and np.array_equal(phi, np.cos(k * 0.01))
