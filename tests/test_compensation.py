"""Issue 19 without real time: --comp-from a diagnose report, the adaptive Coulomb law, the friction_step fault.

* the report's arm friction becomes the compensator (mode chosen from what was found) and the compensator
  built from it cancels the plant's friction law built from the same effects (one definition of each law);
* a bad or unsuitable report is one line, exit 2, before any device is opened;
* the adaptive law (compensation.AdaptiveCoulomb) in closed loop with the simulator: from 0 it converges to
  the arm's Coulomb level; it is bounded, frozen near reversals and at low speed, and frozen outside balancing;
* friction_step@T:Fc=… parses, is refused when malformed, and changes the simulated arm's sliding torque.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from test_bad_input import _call, _check

from furuta_rt.cli import main as furuta_main
from furuta_rt.config import load_rig
from furuta_rt.controller.comp_from import compensation_from_report
from furuta_rt.controller.compensation import AdaptiveCoulomb, Compensator
from furuta_rt.controller.controller import Controller
from furuta_rt.model.effects import Effects
from furuta_rt.model.friction import Coulomb, JointFriction
from furuta_rt.model.rig import RigModel
from furuta_rt.model.sensors import Measurement
from furuta_rt.sim.closed_loop import run_closed_loop
from furuta_rt.sim.simulator import Simulator
from hil_mock.cli import main as mock_main
from hil_mock.faults import parse_fault

RATE = 500
FC_TRUE = 0.35  # N m, the arm Coulomb friction of the simulated rig in the loop test


def report(tmp: Path, effects: dict[str, dict[str, float]], rig: str = "thesis", verdict: str = "explained") -> Path:
    """A report shaped as `furuta-rt diagnose --json` writes it (the keys --comp-from reads, as in a real one)."""
    path = tmp / "report.json"
    body = {
        "summary": "arm equation explained by …",
        "effects": [{"name": k, "params": v} for k, v in effects.items()],
        "equations": {"arm": {"verdict": verdict}, "pendulum": {"verdict": "consistent"}},
        "rig": rig,
    }
    path.write_text(json.dumps(body))
    return path


@pytest.mark.parametrize(("effects", "mode"), [
    ({"arm_coulomb": {"Fc": 0.35}, "command_latency": {"delay": 0.0}}, "coulomb"),
    ({"arm_coulomb": {"Fc": 0.3}, "arm_viscous": {"Fv": 0.02}}, "coulomb"),
    ({"arm_coulomb": {"Fc": 0.3}, "arm_stiction": {"Fs": 0.4}, "arm_viscous": {"Fv": 0.01}}, "stiction"),
    ({"arm_lugre": {"sigma0": 1e4, "sigma1": 1.0, "Fc": 0.3, "Fs": 0.35, "vs": 0.1}}, "lugre"),
    ({"arm_viscous": {"Fv": 0.05}}, "coulomb"),
])
def test_report_friction_becomes_the_compensator_that_cancels_it(tmp_path: Path, effects: dict, mode: str) -> None:
    """The compensator from the report cancels the friction torque of the plant with the report's effects:
    at every sliding speed (beyond eq. 1's ε and the stiction threshold), F̂(v) = −F(v)."""
    rig = load_rig("thesis")
    found = compensation_from_report(str(report(tmp_path, effects)), rig.compensation, rig.name)
    assert found.mode == mode and found.compensation.mode == mode
    assert str(tmp_path / "report.json") in found.source and mode in found.source
    comp = Compensator.from_config(found.compensation, 1.0 / RATE)
    plant = RigModel.from_config(rig, Effects.model_validate(effects)).arm_friction
    for v in (-2.0, -0.5, -0.1, 0.1, 0.5, 2.0):
        if plant.lugre is not None:  # steady sliding: the Stribeck curve, reached by the bristles at constant v
            for _ in range(2000):
                f_hat = comp(v, 0.0)
            expected = plant.lugre.steady_state_force(v)
        else:
            comp.reset()
            f_hat = comp(v, 0.0)
            expected = -sum(law.torque(v) for law in (plant.viscous, plant.dry) if law is not None)
        assert f_hat == pytest.approx(expected, rel=1e-9, abs=1e-12), f"v = {v}: F̂ {f_hat} vs friction {expected}"


def test_unexplained_arm_equation_is_said(tmp_path: Path) -> None:
    rig = load_rig("thesis")
    found = compensation_from_report(str(report(tmp_path, {"arm_coulomb": {"Fc": 0.3}}, verdict="partly_explained")),
                                     rig.compensation, rig.name)
    assert found.mode == "coulomb" and any("partly_explained" in w for w in found.warnings)


BAD_REPORTS: dict[str, tuple[str | None, tuple[str, ...]]] = {
    "missing.json": (None, ("missing.json", "no such file")),
    "not_json.json": ("{effects: [", ("not json",)),
    "a_list.json": ("[1, 2]", ("not a `furuta-rt diagnose --json` report",)),
    "no_effects.json": ('{"summary": "x"}', ("effects",)),
    "bad_entry.json": ('{"effects": [42]}', ("effects",)),
    "negative.json": ('{"effects": [{"name": "arm_coulomb", "params": {"Fc": -0.3}}]}', ("arm_coulomb", "Fc")),
    "null.json": ('{"effects": [{"name": "arm_coulomb", "params": {"Fc": null}}]}', ("arm_coulomb", "Fc")),
    "nan.json": ('{"effects": [{"name": "arm_coulomb", "params": {"Fc": NaN}}]}', ("arm_coulomb", "Fc")),
    "unknown.json": ('{"effects": [{"name": "warp_drive", "params": {"x": 1}}]}', ("warp_drive",)),
    "other_rig.json": ('{"rig": "qube_servo2", "effects": [{"name": "arm_coulomb", "params": {"Fc": 0.3}}]}',
                       ("qube_servo2", "thesis")),
    "no_arm.json": ('{"rig": "thesis", "effects": [{"name": "theta_offset", "params": {"offset": 0.01}}]}',
                    ("no arm friction", "theta_offset")),
}


@pytest.mark.parametrize("name", list(BAD_REPORTS))
def test_bad_report_is_one_line_exit_2(tmp_path: Path, name: str) -> None:
    text, mentions = BAD_REPORTS[name]
    path = tmp_path / name
    if text is not None:
        path.write_text(text)
    rc, _, err = _call(furuta_main, ["run", "--mock", "--duration", "1", "--comp-from", str(path)])
    _check(rc, err, "--comp-from", *mentions)


def test_comp_and_comp_from_together_is_one_line_exit_2(tmp_path: Path) -> None:
    path = report(tmp_path, {"arm_coulomb": {"Fc": 0.3}})
    rc, _, err = _call(furuta_main, ["run", "--mock", "--duration", "1", "--comp", "coulomb", "--comp-from", str(path)])
    _check(rc, err, "--comp-from", "--comp")


# ------------------------------------------------------------------ the adaptive law
def closed_loop_estimate(fc_true: float, seconds: float, step: tuple[float, float] | None = None,
                         seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Balance the simulated thesis rig (arm Coulomb ``fc_true``, ideal set-valued) with --comp adaptive from 0;
    ``step`` = (t, Fc): the friction changes then. Returns t, F̂c per tick, φ per tick."""
    rig = load_rig("thesis")
    sim = Simulator(RigModel.from_config(rig, Effects.model_validate({"arm_coulomb": {"Fc": fc_true}})),
                    RATE, 10_000, seed=seed, x0=(0.05, 0.0, 0.0, 0.0))
    ctrl = Controller.from_rig(rig, mode="adaptive")
    n = round(seconds * RATE)
    fc, phi = np.empty(n), np.empty(n)
    for k in range(n):
        if step is not None and k == round(step[0] * RATE):
            sim.set_arm_friction(JointFriction(dry=Coulomb(step[1])))
        m = sim.measure()
        out = ctrl.update(m)
        fc[k], phi[k] = ctrl.compensator.coulomb_level, m.phi
        sim.advance()
        sim.set_command(out.u)
    return np.arange(n) / RATE, fc, phi


def settled_after(t: np.ndarray, est: np.ndarray, target: float, tol: float = 0.1) -> float:
    """The time from which the estimate stays within ``tol`` of ``target`` (inf: never)."""
    outside = np.flatnonzero(np.abs(est - target) > tol * target)
    if outside.size == 0:
        return float(t[0])
    return float(t[outside[-1] + 1]) if outside[-1] + 1 < t.size else math.inf


def test_adaptive_law_converges_from_zero_and_follows_a_friction_step() -> None:
    """From F̂c = 0 the estimate reaches the arm's Coulomb level within 10 % in a few seconds and stays there;
    the friction limit cycle dies out; after a step 0.35 → 0.5 N m it re-converges."""
    t, fc, phi = closed_loop_estimate(0.35, 16.0, step=(8.0, 0.5))
    first = t < 8.0
    t_conv = settled_after(t[first], fc[first], 0.35)
    assert t_conv < 5.0, f"F̂c {fc[first][:: RATE]} does not settle within 10 % of 0.35 N m"
    assert np.std(phi[(t >= 5.0) & first]) < 0.05  # the 0.4 rad limit cycle of no compensation is gone
    t_re = settled_after(t[~first], fc[~first], 0.5) - 8.0
    assert t_re < 5.0, f"after the step F̂c {fc[~first][:: RATE]} does not settle within 10 % of 0.5 N m"


def slide(law: AdaptiveCoulomb, residual: float, v: float, ticks: int, phi0: float = 0.0) -> float:
    """Feed ``ticks`` ticks of the arm sliding at ``v`` rad/s with a constant torque residual; returns the last φ."""
    phi = phi0
    for _ in range(ticks):
        phi += v / RATE
        law.adapt(residual, v, phi)
    return phi


def test_adaptive_law_moves_per_window_is_bounded_and_frozen_where_unsure() -> None:
    window = 5
    law = AdaptiveCoulomb(fc0=0.2, fc_max=0.5, time_constant=0.1, epsilon=0.01, v_min=0.1, window_ticks=window,
                          period=1.0 / RATE)
    step = (1.0 / RATE) / 0.1  # h / T_a
    phi = slide(law, -1.0, 0.05, 10 * window)  # below v_min: the arm may be sticking
    assert law.fc_hat == 0.2
    for v in (-0.5, 0.5) * 10:  # reversals before a window fills: the sign of φ̇ is not sure
        phi = slide(law, -1.0, v, window - 1, phi)
    assert law.fc_hat == 0.2
    law.reset()
    phi = slide(law, -1.0, 0.5, 1 + window, phi)  # the first tick opens the window, then one full window
    # r̂ = −1 N m while sliding forward: the friction is 1 N m larger than F̂c; one window moves F̂c by window·h/T_a
    assert law.fc_hat == pytest.approx(0.2 + step * window * 1.0)
    phi = slide(law, -10.0, 0.5, 100 * window, phi)
    assert law.fc_hat == 0.5  # bounded above by Fc_max
    # sliding backwards with r̂ negative (along the motion): F̂c is too large; down to 0 and no further
    phi = slide(law, -10.0, -0.5, 100 * window, phi)
    assert law.fc_hat == 0.0 and law.compensation(-0.5) == 0.0


def test_adaptive_estimate_is_frozen_outside_balancing() -> None:
    """Controller.hold (idle, armed, tripped) never adapts; the estimate survives a re-arm (reset)."""
    rig = load_rig("thesis")
    ctrl = Controller.from_rig(rig, mode="adaptive")
    adaptive = ctrl.compensator.adaptive
    assert adaptive is not None
    adaptive.fc_hat = 0.3
    for k in range(500):  # the arm swinging by hand at 1 rad/s: plenty of innovation
        ctrl.hold(Measurement(k / RATE, 0.0, 0.0, math.sin(k / RATE)))
    assert adaptive.fc_hat == 0.3
    ctrl.reset(0.0)
    assert adaptive.fc_hat == 0.3


# ------------------------------------------------------------------ friction_step
def test_friction_step_parses_and_bad_forms_are_refused() -> None:
    ev = parse_fault("friction_step@8:Fc=0.5")
    assert ev.kind == "friction_step" and ev.at == 8.0 and dict(ev.params) == {"Fc": 0.5}
    assert str(ev) == "friction_step@8:Fc=0.5"
    assert dict(parse_fault("friction_step@2.5:Fc=0.3,Fs=0.4").params) == {"Fc": 0.3, "Fs": 0.4}
    for bad in ("friction_step@8", "friction_step@8:Fv=1", "friction_step@8:Fc=abc", "friction_step@8:Fc=-1",
                "friction_step@8:Fc=0.5,Fs=0.2", "friction_step@x:Fc=1"):
        with pytest.raises(ValueError, match="friction_step"):
            parse_fault(bad)


@pytest.mark.parametrize("fault", ["friction_step@3", "friction_step@3:Fc=-0.1", "friction_step@3:mu=0.1"])
def test_bad_friction_step_is_one_line_exit_2(fault: str) -> None:
    rc, _, err = _call(mock_main, ["--pty", "--duration", "0.1", "--fault", fault])
    _check(rc, err, "friction_step")


def test_friction_step_changes_the_simulated_arm_friction() -> None:
    """The arm driven by a steady 1 N m slides against Fc: 0.35 N m before the step, 0.6 N m after it."""
    rig = load_rig("thesis")
    model = RigModel.from_config(rig, Effects.model_validate({"arm_coulomb": {"Fc": 0.35}}))
    sim = Simulator(model, RATE, 10_000, x0=(0.0, 0.0, 0.0, 0.0))
    sim.set_command(0.5)
    for _ in range(50):
        sim.advance()
    before = sim.arm_friction_torque
    sim.set_arm_friction(JointFriction(dry=Coulomb(0.45)))
    sim.advance()
    assert before == pytest.approx(-0.35) and sim.arm_friction_torque == pytest.approx(-0.45)
    assert sim.model.arm_friction.dry == Coulomb(0.45)


def test_adaptive_estimate_goes_to_every_log_record_and_the_dashboard() -> None:
    """The real ControlLoop against the simulator (arm Coulomb 0.35 N m) with --comp adaptive: every tick record
    carries the estimate the controller used (re-running the logged measurements through a fresh controller
    gives the same estimate, tick for tick), it has learnt the friction within 10 % in 3 s, and the dashboard
    shows it."""
    from rich.console import Console
    from test_run_loop import F, SimDevice, _col, make_loop

    from furuta_rt.model.effects import ArmCoulomb
    from furuta_rt.runtime.dashboard import render
    from furuta_rt.runtime.records import STATE_NAMES

    rig = load_rig("thesis")
    rig = rig.model_copy(update={"effects": Effects(arm_coulomb=ArmCoulomb(Fc=FC_TRUE))})
    ctrl = Controller.from_rig(rig, mode="adaptive")
    loop, sink = make_loop(rig, SimDevice(rig), duration=3.0, controller=ctrl)
    loop.mode = "adaptive"
    snaps: list[dict] = []

    class Snaps:
        def put_nowait(self, item: dict) -> None:
            snaps.append(item)

    loop.dashboard = Snaps()
    loop.run()
    ticks = sink.ticks()
    logged = _col(ticks, "fc_hat")
    assert logged[0] == 0.0 and logged[-1] == ctrl.compensator.coulomb_level
    assert logged[-1] == pytest.approx(FC_TRUE, rel=0.1)
    replay = Controller.from_rig(rig, mode="adaptive")
    for rec, fc in zip(ticks, logged, strict=True):
        m = Measurement(rec[F["t"]], rec[F["theta"]], rec[F["theta_dot"]], rec[F["phi"]])
        if rec[F["reset"]]:
            replay.reset(m.phi)
        if STATE_NAMES[rec[F["state"]]] == "balancing":
            replay.update(m)
        else:
            replay.hold(m)
        assert replay.compensator.coulomb_level == fc
    console = Console(record=True, width=140)
    console.print(render(snaps[-1]))
    line = next(ln for ln in console.export_text().splitlines() if "Fc estimate" in ln)
    assert f"{snaps[-1]['fc_hat']:.4f} N m" in line and snaps[-1]["fc_hat"] > 0.3


def test_adaptive_on_a_voltage_driven_rig_learns_the_torque() -> None:
    """The QUBE-Servo 2 (u in volts): the law works in N m through the motor's R/Kt, so its estimate is the arm's
    Coulomb torque (5 mN m here) and the friction limit cycle of the uncompensated loop goes."""
    rig = load_rig("qube_servo2")
    eff = Effects.model_validate({"arm_coulomb": {"Fc": 0.005}})
    after = int(6 * rig.control.rate_hz)
    none = run_closed_loop(rig, 12.0, effects=eff, mode="none")
    rec = run_closed_loop(rig, 12.0, effects=eff, mode="adaptive")
    replay = Controller.from_rig(rig, mode="adaptive")  # the run's controller, re-run to read its estimate
    for k in range(len(rec.t)):
        replay.update(Measurement(rec.t[k], rec.theta[k], rec.theta_dot[k], rec.phi[k]))  # type: ignore[index]
    assert replay.compensator.coulomb_level == pytest.approx(0.005, rel=0.1)
    assert np.std(none.phi[after:]) / np.std(rec.phi[after:]) >= 5.0
