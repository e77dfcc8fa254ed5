"""One command-timing rule in every simulated loop (furuta_rt.sim.command_path): the command answering the sample of
tick k acts from t_k + command_delay_ticks·h unless a ``command_latency`` states the whole lag. Each loop must give the
same trajectory for a rig that states its lag as ``command_delay_ticks`` and for the same rig with the equal
``command_latency``; and a shorter lag must change the trajectory (the rule is not ignored)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from furuta_rt.config import RigConfig, load_rig
from furuta_rt.io.recordings import read_recording
from furuta_rt.model.effects import Effects
from furuta_rt.model.rig import RigModel
from furuta_rt.replay.simulate import simulate_log
from furuta_rt.sim.closed_loop import run_closed_loop
from furuta_rt.sim.command_path import CommandPath
from furuta_rt.sim.simulator import Simulator
from furuta_rt.sim.swingup_run import simulate_swing_up


def _with_delay_ticks(rig: RigConfig, ticks: int) -> RigConfig:
    return rig.model_copy(update={"control": rig.control.model_copy(update={"command_delay_ticks": ticks})})


def _latency(rig: RigConfig, ticks: int) -> Effects:
    return Effects.model_validate({"command_latency": {"delay": ticks / rig.control.rate_hz}})


@pytest.mark.parametrize("ticks", [0, 1, 2])
def test_closed_loop_honours_command_delay_ticks(ticks: int) -> None:
    rig = _with_delay_ticks(load_rig("thesis"), ticks)
    stated = run_closed_loop(rig, 0.6, seed=3)
    total = run_closed_loop(rig, 0.6, seed=3, effects=_latency(rig, ticks))
    assert np.array_equal(stated.theta, total.theta) and np.array_equal(stated.u, total.u)
    other = run_closed_loop(rig, 0.6, seed=3, effects=_latency(rig, ticks + 1))
    assert not np.array_equal(stated.theta, other.theta)


@pytest.mark.parametrize("ticks", [0, 1])
def test_swing_up_honours_the_same_rule(ticks: int) -> None:
    rig = _with_delay_ticks(load_rig("thesis"), ticks)
    stated = simulate_swing_up(rig, 0.5, seed=1)
    total = simulate_swing_up(rig, 0.5, seed=1, effects=_latency(rig, ticks))
    assert np.array_equal(stated.true_state, total.true_state) and np.array_equal(stated.u, total.u)
    assert np.max(np.abs(stated.u)) > 0  # the swing-up pumped: the commands reached the plant


@pytest.mark.parametrize("ticks", [0, 1])
def test_simulated_log_honours_the_same_rule(tmp_path, ticks: int) -> None:
    rig = _with_delay_ticks(load_rig("thesis"), ticks)
    a = read_recording(simulate_log(tmp_path / "a.mcap", rig, 0.4, seed=2, idle=0.05))
    b = read_recording(simulate_log(tmp_path / "b.mcap", rig, 0.4, seed=2, idle=0.05, effects=_latency(rig, ticks)))
    assert np.array_equal(a.theta, b.theta) and np.array_equal(a.u, b.u)


def test_a_command_acts_command_delay_ticks_after_its_sample() -> None:
    """At the device side: a step command answering the sample at t = 0 moves the arm from t = D·h on, not before."""
    for ticks in (0, 1, 2):
        rig = _with_delay_ticks(load_rig("thesis"), ticks)
        sim = Simulator(RigModel.from_config(rig), rig.control.rate_hz, x0=(math.pi, 0.0, 0.0, 0.0))
        path = CommandPath(sim, ticks)
        speeds = []
        for k in range(4):
            path.send_and_advance(0.2 if k == 0 else 0.0)
            speeds.append(abs(sim.phi_dot))
        assert all(s < 1e-12 for s in speeds[:ticks]) and speeds[ticks] > 1e-4, (ticks, speeds)


@pytest.mark.parametrize("ticks", [0, 1])
def test_the_periodic_orbit_loop_honours_the_same_rule(ticks: int) -> None:
    """analysis.periodic_orbit's SampledLoop (the controller on the simulator, stepped tick by tick)."""
    from furuta_rt.analysis.periodic_orbit import SampledLoop

    rig = _with_delay_ticks(load_rig("thesis"), ticks)
    coulomb = {"arm_coulomb": {"Fc": 0.02}}

    def run(effects: dict) -> np.ndarray:
        loop = SampledLoop(rig, None, Effects.model_validate(effects))
        loop.set(np.r_[0.05, 0.0, 0.0, 0.0, loop.get()[4:]])
        out = []
        for _ in range(150):
            loop.step()
            out.append(loop.get()[:4])
        return np.array(out)

    stated = run(coulomb)
    assert np.array_equal(stated, run({**coulomb, "command_latency": {"delay": ticks / rig.control.rate_hz}}))
    assert not np.array_equal(stated, run({**coulomb, "command_latency": {"delay": (ticks + 1) / rig.control.rate_hz}}))


def test_the_rule_and_its_inverse() -> None:
    """effects.command_timing: (driver ticks, delay line) — command_delay_ticks and input_delay, or 0 and the whole
    command_latency; total_latency its ticks·h + delay; latency_effect names the effect that carries a total."""
    from furuta_rt.model.effects import command_timing, latency_effect, total_latency

    rig = load_rig("thesis")  # 500 Hz, one tick
    h = 1 / rig.control.rate_hz
    assert command_timing(1, 0.003, None) == (1, 0.003) and command_timing(1, 0.003, 0.001) == (0, 0.001)
    for eff, total in (({}, h), ({"input_delay": {"delay": 0.003}}, h + 0.003), ({"command_latency": {"delay": 0.001}}, 0.001)):
        e = Effects.model_validate(eff)
        assert total_latency(e, 1, rig.control.rate_hz) == pytest.approx(total)
        ticks, delay = RigModel.from_config(rig, e).command_timing(1)
        assert ticks * h + delay == pytest.approx(total)
    assert latency_effect(h + 0.003, h) == ("input_delay", pytest.approx(0.003))
    assert latency_effect(0.001, h) == ("command_latency", 0.001) and latency_effect(h, h) == ("command_latency", h)
