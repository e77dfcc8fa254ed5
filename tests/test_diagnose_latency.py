"""The command latency profiled jointly with the arm's linear parameters (furuta_rt.diagnose.stages.latency, issue 14)."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.suite_realistic import simulate
from furuta_rt.config import load_rig
from furuta_rt.diagnose import Options, diagnose
from furuta_rt.model.effects import effects_from_assignments

FAST = Options(closed_loop=False, max_windows=15)


def _total_latency(rig, found: dict[str, dict[str, float]]) -> float:
    h = 1.0 / rig.control.rate_hz
    if "command_latency" in found:
        return found["command_latency"]["delay"]
    return rig.control.command_delay_ticks * h + found.get("input_delay", {}).get("delay", 0.0)


def _case(shape: str, excitation: str, seed: int, effects: list[str]):
    rig = load_rig(shape)
    rec = simulate(rig, shape, effects_from_assignments(effects), excitation, 20.0, seed)
    return rig, diagnose(rec, rig, FAST)


@pytest.mark.parametrize("ticks", [0.0, 3.0])
def test_latency_off_the_config_is_measured_next_to_wrong_gain_and_inertia(ticks: float) -> None:
    """A QUBE-shaped DC-motor rig, torque per volt ×0.6 and arm inertia ×0.7, a chirp: the total latency (one tick in
    the config) within half a tick, as command_latency when shorter, input_delay when longer, and the arm inertia
    within 5 %. (Three ticks: the selection alone said 1.6; lag and ΔJ profiled one after the other, 2.24 with J 8 %
    high — they trade phase, so they are profiled together.)"""
    rig = load_rig("qube_servo2")
    h = 1.0 / rig.control.rate_hz
    J = 0.7 * rig.plant.arm_inertia
    eff = ["input_gain.gain=0.6", f"arm_inertia.J={J:.4g}", "arm_viscous.Fv=0.0015", f"command_latency.delay={ticks * h}"]
    rig, d = _case("qube_servo2", "chirp", 901 + int(ticks), eff)
    found = {e.name: e.params for e in d.effects}
    assert abs(_total_latency(rig, found) - ticks * h) < 0.5 * h, found
    assert found["arm_inertia"]["J"] == pytest.approx(J, rel=0.05)
    assert ("command_latency" in found) == (ticks < 1) and ("input_delay" in found) == (ticks > 1), found
    row = next(r for r in d.equations["arm"].trace if r["candidate"] == "latency (joint)")
    assert row["accepted"] and row["params"]["se"] < 0.5 * h


def test_the_configured_latency_is_not_reported_when_the_inertia_is_off() -> None:
    """The latency the config says, an arm inertia ×0.5 (a phase lead a shorter latency could mimic): no latency
    effect, the joint profile's optimum within a quarter tick of the config's."""
    rig = load_rig("macstepien")
    h = 1.0 / rig.control.rate_hz
    J = 0.5 * rig.plant.arm_inertia
    rig, d = _case("macstepien", "sine", 911, ["input_gain.gain=5", f"arm_inertia.J={J:.4g}", "arm_viscous.Fv=0.0117"])
    found = {e.name for e in d.effects}
    assert not {"command_latency", "input_delay"} & found, found
    row = next(r for r in d.equations["arm"].trace if r["candidate"] == "latency (joint)")
    assert not row["accepted"]
    assert abs(row["params"]["total"] - rig.control.command_delay_ticks * h) < 0.25 * h
    assert np.isfinite(row["cv_gain"])
