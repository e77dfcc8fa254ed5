"""Summary statistics: the limit cycle found when there is a clear one (thesis sections 5-6: Coulomb
friction on the arm makes the balanced pendulum oscillate), and not in noise."""

from __future__ import annotations

import numpy as np
import pytest

from furuta_rt.config import load_rig
from furuta_rt.model.effects import effects_from_assignments
from furuta_rt.recording import Recording
from furuta_rt.sim.closed_loop import run_closed_loop
from furuta_rt.stats import limit_cycle_stats, summary_stats

T = np.arange(0.0, 20.0, 0.002)


@pytest.mark.parametrize(("period", "amplitude"), [(1.3, 0.1), (4.2, 0.4), (0.25, 0.01)])
def test_sine_with_noise_and_drift(period: float, amplitude: float) -> None:
    rng = np.random.default_rng(0)
    x = amplitude * np.sin(2 * np.pi * T / period) + 0.1 * amplitude * rng.standard_normal(len(T)) + 0.01 * T
    lc = limit_cycle_stats(T, x)
    assert lc is not None
    assert lc.period == pytest.approx(period, rel=0.02)
    assert lc.amplitude == pytest.approx(amplitude, rel=0.05)
    assert lc.cycles >= 3 and lc.autocorrelation > 0.9  # many cycles here


@pytest.mark.parametrize("x", [
    np.random.default_rng(1).standard_normal(len(T)),  # noise
    np.exp(-T),  # a decay
    np.sin(2 * np.pi * T / 15.0),  # one cycle and a bit: too few to call it periodic
    np.sin(2 * np.pi * T**2 / 20.0),  # a chirp: no single period
    np.zeros(len(T)),
])
def test_no_clear_oscillation(x: np.ndarray) -> None:
    assert limit_cycle_stats(T, x) is None


def test_two_cycles_are_enough() -> None:
    """The README's demo (`--mock-effect arm_coulomb.Fc=0.3`, 10 s): φ swings ±0.42 rad with a period of
    ~4.2 s, two cycles in the log, as a clipped (square-ish) wave; found, with its amplitude and period."""
    t = np.arange(0.0, 9.0, 0.002)
    rng = np.random.default_rng(3)
    x = np.clip(1.6 * np.sin(2 * np.pi * (t - 0.4) / 4.2), -1, 1) * 0.42 + 0.002 * rng.standard_normal(len(t))
    lc = limit_cycle_stats(t, x)
    assert lc is not None and lc.cycles == 2
    assert lc.period == pytest.approx(4.2, rel=0.02)
    assert lc.amplitude == pytest.approx(0.42, rel=0.03)


def test_no_cycle_on_a_clean_balance_or_a_wandering_arm() -> None:
    """No friction: the balanced loop of the thesis rig (its sensors' noise and quantisation) holds no limit
    cycle; nor does a random walk or low-pass noise of the arm (50 draws each)."""
    rec = run_closed_loop(load_rig("thesis"), 10.0, substep_hz=2000)
    assert limit_cycle_stats(rec.t, rec.phi) is None and limit_cycle_stats(rec.t, rec.theta) is None
    t = T[:5000]
    for seed in range(50):
        w = np.random.default_rng(seed).standard_normal(len(t))
        assert limit_cycle_stats(t, np.cumsum(w)) is None
        smooth = np.convolve(w, np.ones(500) / 500, mode="same")  # wanders on a 1 s scale
        assert limit_cycle_stats(t, smooth) is None


def test_coulomb_friction_limit_cycle_and_summary() -> None:
    rig = load_rig("thesis")
    rec = run_closed_loop(rig, 25.0, effects=effects_from_assignments(["arm_coulomb.Fc=0.3"]), substep_hz=2000)
    s = summary_stats(rec, start=5.0)
    lc = s["limit_cycle_phi"]
    assert lc is not None and 2.0 < lc["period"] < 8.0 and lc["amplitude"] > 0.1
    assert s["limit_cycle_theta"] is not None
    assert s["limit_cycle_theta"]["period"] == pytest.approx(lc["period"], rel=0.05)
    assert s["phi"]["std"] == pytest.approx(np.std(rec.phi[rec.t >= 5.0]))
    quiet = summary_stats(Recording(t=T, theta=0 * T, phi=0 * T, u=0 * T))
    assert quiet["limit_cycle_phi"] is None and quiet["u"]["std"] == 0.0
