"""The effect registry (furuta_rt.model.effects.EFFECT_TYPES): one class per effect, read by the rig configuration,
the simulator and diagnose's regression library; and the effect added through it alone (arm_air_drag)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from furuta_rt.config import load_rig
from furuta_rt.diagnose.regression.library import CANDIDATES
from furuta_rt.diagnose.stages.lookalikes import EXPERIMENTS
from furuta_rt.model.effects import ARM, EFFECT_TYPES, PEND, Effects, JointTorque, parse_effect_assignment
from furuta_rt.model.rig import RigModel
from furuta_rt.sim.compiled import make_simulator, unsupported
from furuta_rt.sim.simulator import Simulator


def test_every_registered_effect_is_a_config_field_an_assignment_and_a_consistent_entry() -> None:
    assert list(Effects.model_fields) == list(EFFECT_TYPES)
    for name, cls in EFFECT_TYPES.items():
        assert cls.name == name and cls.equation in (ARM, PEND) and cls.main in cls.model_fields
        assert parse_effect_assignment(f"{name}.{cls.main}=0.5")[:2] == (name, cls.main)
        assert set(cls.lookalikes) <= set(EFFECT_TYPES) and name not in cls.lookalikes
        for other in cls.experiments:
            assert other in EFFECT_TYPES and EXPERIMENTS[frozenset({name, other})] == cls.experiments[other]
    for name, cand in CANDIDATES.items():  # the regression sees the registry's row, size parameter and look-alikes
        cls = EFFECT_TYPES[name]
        assert (cand.equation, cand.main, cand.lookalikes) == (cls.equation, cls.main, cls.lookalikes)
    # the registry's sign rule (a parameter bounded below by 0 is > 0) judges the torque laws only; a spelled-out
    # effect keeps the library's own rule (a dead band of width 0 is judged by its kinks, not refused by its sign)
    rig = load_rig("thesis")
    assert CANDIDATES["input_deadzone"].plausible({"width": 0.0}, rig)
    assert not CANDIDATES["arm_air_drag"].plausible({"c": 0.0}, rig) and CANDIDATES["arm_air_drag"].plausible({"c": 1e-4}, rig)
    # every torque-law effect is a regression candidate without any entry of its own in the library
    assert {n for n, c in EFFECT_TYPES.items() if issubclass(c, JointTorque)} <= set(CANDIDATES)


def test_a_torque_law_effect_enters_the_rig_model_and_its_row_of_eq_4() -> None:
    """arm_air_drag: RigModel carries it, its torque is −c·φ̇|φ̇| on the arm and nothing on the pendulum, and a
    coasting arm with only that drag slows as the closed form of J_eff·φ̈ = −c·φ̇² says (pendulum hanging still)."""
    rig = load_rig("thesis")
    assert RigModel.from_config(rig).joint_torques == ()
    c = 0.02
    model = RigModel.from_config(rig, Effects.model_validate({"arm_air_drag": {"c": c}}))
    (drag,) = model.joint_torques
    assert "arm_air_drag" in (unsupported(model) or "")  # plant.c has no torque laws: hil-mock runs the Python plant
    assert type(make_simulator(model)) is Simulator and unsupported(RigModel.from_config(rig)) is None
    assert model.joint_torque(0.1, 0.2, 0.3, -2.0) == (0.0, pytest.approx(c * 4.0))
    assert drag.torque(0.0, 0.0, 0.0, np.array([1.0, -3.0])) == pytest.approx([-c, 9 * c])
    # hanging, the arm coasting from 5 rad/s with only the drag on it: eq. 4's energy falls by the drag's work,
    # dE/dt = τ·φ̇ = −c·|φ̇|³ (the pendulum, swung by the arm's deceleration, exchanges energy but loses none)
    sim = Simulator(model, seed=0, x0=(math.pi, 0.0, 0.0, 5.0))
    e0, speeds = sim.energy(), [sim.phi_dot]
    for _ in range(500):  # 1 s
        sim.advance()
        speeds.append(sim.phi_dot)
    work = np.trapezoid(-c * np.abs(speeds) ** 3, dx=1 / 500)
    assert sim.phi_dot < 2.0 and sim.energy() - e0 == pytest.approx(work, rel=1e-3)


C_DRAG = 0.01  # N m s²/rad²: a flag on the arm; 0.02 N m at the 1.5 rad/s the square reference reaches


BALANCING_S = 18.0  # three periods of the square reference (6 s each): enough for c's standard error to be 1/9 of the bound


def _balancing(c: float):
    """BALANCING_S of the thesis rig balancing with the suite's square arm reference (seed 5), air drag c on the arm."""
    from benchmarks.suite import reference_signal
    from furuta_rt.sim.closed_loop import run_closed_loop

    rig = load_rig("thesis")
    n = int(BALANCING_S * rig.control.rate_hz)
    eff = Effects.model_validate({"arm_air_drag": {"c": c}} if c else {})
    return rig, run_closed_loop(rig, BALANCING_S, effects=eff, seed=5, reference=reference_signal("square", n, 500.0, 5))


def test_diagnose_finds_air_drag_concealed_in_a_recording_and_not_where_there_is_none() -> None:
    """The effect added through the registry alone is found by diagnose's regression: concealed at c = 0.01 it is
    named (told apart from its look-alike, viscous friction) with c within 4 standard errors of the truth and a
    standard error under 5 % of it (measured: 0.01004 ± 0.00005); the same run without it names no effect."""
    from furuta_rt.diagnose import Options, diagnose

    opts = Options(closed_loop=False, also_search=("arm_air_drag",))  # outside the default search: asked for
    rig, rec = _balancing(C_DRAG)
    d = diagnose(rec, rig, opts)
    (drag,) = [e for e in d.effects if e.name == "arm_air_drag"]
    assert abs(drag.params["c"] - C_DRAG) <= 4 * drag.se["c"] and drag.se["c"] < 0.05 * C_DRAG
    assert any(a["effects"] == ["arm_air_drag", "arm_viscous"] and a["reported"] == "arm_air_drag" for a in d.lookalikes)
    assert d.verdicts["arm"].verdict == "explained"
    rig, rec = _balancing(0.0)
    assert diagnose(rec, rig, opts).names == []


def test_air_drag_is_tried_only_when_asked() -> None:
    """Outside the default search (its column trades with the arm inertia and the input gain on balancing data):
    `diagnose --also-search arm_air_drag` asks for it; a name that is searched already, or no effect, is one line."""
    import argparse

    from furuta_rt.cli.diagnose import _options
    from furuta_rt.errors import UserError

    assert not CANDIDATES["arm_air_drag"].searched and CANDIDATES["arm_viscous"].searched

    def ns(*names: str) -> argparse.Namespace:
        return argparse.Namespace(no_closed_loop=True, skip_convention_check=False, also_search=list(names))

    assert _options(ns("arm_air_drag")).also_search == ("arm_air_drag",) and _options(ns()).also_search == ()
    for name, why in (("arm_coulomb", "is searched already"), ("arm_drag", "is not a registered effect")):
        with pytest.raises(UserError, match=why) as err:
            _options(ns(name))
        assert "arm_air_drag" in str(err.value) and "\n" not in str(err.value)


def test_the_regression_reads_every_effect_from_its_class_alone() -> None:
    """No effect is handled by name in the regression library: it holds no `match` and no registered effect's name in
    its Candidate; each candidate's columns, parameters, plausibility and nonlinear parameter are its class's."""
    import ast
    import inspect

    from furuta_rt.diagnose.regression import library

    tree = ast.parse(inspect.getsource(library))
    assert not any(isinstance(n, ast.Match) for n in ast.walk(tree))
    cand = next(n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == "Candidate")
    assert not {c.value for c in ast.walk(cand) if isinstance(c, ast.Constant)} & set(EFFECT_TYPES)
    assert list(CANDIDATES) == [n for n, c in EFFECT_TYPES.items() if c.regressed]  # the registry's order is the search's
    assert "arm_stiction" not in CANDIDATES  # measured on the stick windows, not by the regression
    # the command path's effects are tried only on a recording with a command (on_command), nothing else is held back
    assert {n for n, c in EFFECT_TYPES.items() if c.on_command} == {
        "input_gain", "input_delay", "input_deadzone", "input_saturation"}
    for name, cand in CANDIDATES.items():
        cls = EFFECT_TYPES[name]
        assert (cand.nonlinear, cand.requires, cand.excludes) == (cls.nonlinear, cls.requires, cls.excludes)
        assert all(EFFECT_TYPES[e].regressed for e in (*cand.excludes, *filter(None, [cand.requires])))


def test_an_effect_with_its_own_columns_is_a_candidate_by_its_class_alone(monkeypatch) -> None:
    """A spelled-out effect (not a torque law): a class with its own columns and nothing in the library is fitted like
    the built-in effect of the same physics. A twin of arm_bias written as a new class reads the same constant torque,
    to the last digit, from a recording of the thesis rig with a 0.05 N m bias, and is refused like it when negative."""
    from benchmarks.suite import reference_signal
    from furuta_rt.diagnose import Options
    from furuta_rt.diagnose.regression.library import Candidate, Context
    from furuta_rt.diagnose.regression.selection import EquationModel
    from furuta_rt.diagnose.regression.states import prepare
    from furuta_rt.diagnose.stages.start import arm_sigma
    from furuta_rt.model.effects import Effect
    from furuta_rt.sim.closed_loop import run_closed_loop

    class ArmBiasTwin(Effect):  # what a contributor would write in model/effects.py
        name = "arm_bias_twin"
        tau: float = 0.0

        @classmethod
        def columns(cls, ctx, path, vs):
            return np.ones((ctx.prep.n, 1))

        @classmethod
        def plausible(cls, par, rig, travel):
            return par["tau"] > 0

    try:
        monkeypatch.setitem(CANDIDATES, "arm_bias_twin", Candidate("arm_bias_twin"))
        rig = load_rig("thesis")
        rec = run_closed_loop(rig, 12.0, effects=Effects.model_validate({"arm_bias": {"tau": 0.05}}), seed=4,
                              reference=reference_signal("sine", 6000, 500.0, 4))
        o = Options()
        prep = prepare(rec, rig)
        ctx = Context.build(prep, rig, arm_sigma(prep), o.sigma_pend, o.sigma_fine)
        em = EquationModel(ctx, ARM, o.thresholds)
        twin = em.evaluate(em.spec0().with_effect("arm_bias_twin"))
        built_in = em.evaluate(em.spec0().with_effect("arm_bias"))
        assert twin.params["arm_bias_twin"]["tau"] == built_in.params["arm_bias"]["tau"]
        assert abs(twin.params["arm_bias_twin"]["tau"] - 0.05) < 0.005 and twin.cv == built_in.cv
        assert CANDIDATES["arm_bias_twin"].plausible({"tau": 0.05}, rig)
        assert not CANDIDATES["arm_bias_twin"].plausible({"tau": -0.05}, rig)
    finally:
        EFFECT_TYPES.pop("arm_bias_twin", None)
