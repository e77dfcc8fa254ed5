"""The regression's profiles take what does not change along a nonlinear parameter once (selection.EquationModel.profile):
the statistics they give must be the ones ``stats`` gives at each value, to the last bit, for one recording and for a
joint fit of two (stacked rows, a per-recording column)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from benchmarks import suite
from furuta_rt.config import load_rig
from furuta_rt.diagnose.joint import JointEquationModel
from furuta_rt.diagnose.regression.fitting import Stats, _column_sums
from furuta_rt.diagnose.regression.library import ARM, PEND
from furuta_rt.diagnose.regression.selection import EquationModel, Thresholds
from furuta_rt.diagnose.stages.findings import Options
from furuta_rt.diagnose.stages.start import start


def same(a: Stats, b: Stats) -> bool:
    return all(np.array_equal(getattr(a, f.name), getattr(b, f.name)) for f in dataclasses.fields(Stats))


@pytest.mark.parametrize("shape", [(5, 2), (8192, 3), (12001, 4), (3000, 1), (0, 3), (400, 7)])
def test_column_sums_are_numpys_own(shape) -> None:
    a = np.random.default_rng(shape[0]).standard_normal(shape) ** 2 * np.geomspace(1e-3, 1e3, shape[1])
    assert np.array_equal(_column_sums(a), np.sum(a, axis=0))


@pytest.fixture(scope="module")
def models() -> dict[str, EquationModel]:
    rig = load_rig("thesis")
    case = next(c for c in suite.quick_cases() if c.name == "arm_coulomb")
    ctxs = [start(suite.generate(dataclasses.replace(case, duration=6.0, seed=s), rig), rig, Options()).ctx
            for s in (case.seed, case.seed + 1)]
    th = Thresholds()
    arm = [EquationModel(c, ARM, th) for c in ctxs]
    return {"arm": arm[0], "pendulum": EquationModel(ctxs[0], PEND, th), "joint": JointEquationModel(arm)}


@pytest.mark.parametrize("which", ["arm", "joint"])
@pytest.mark.parametrize(("effects", "kind", "name"), [
    ((), "inertia", "arm_inertia"),
    (("arm_coulomb", "arm_spring"), "inertia", "arm_inertia"),
    (("arm_coulomb",), "delay", "input_delay"),
    (("arm_coulomb", "arm_inertia"), "deadzone", "input_deadzone"),  # a fixed ΔJ weights the rows
    (("input_gain",), "limit", "input_saturation"),  # a column that moves with the command path
])
def test_a_profile_gives_the_statistics_of_each_value(models, which, effects, kind, name) -> None:
    em = models[which]
    spec = em.spec0()
    for e in (*effects, name):
        spec = spec.with_effect(e)
    if "arm_inertia" in effects:
        spec = spec.with_value("inertia", 0.3 * em.ctx.base_inertia)
    profile = em.profile(spec, kind)
    grid = em.grid(kind)
    for value in ((0.0,) if kind != "limit" else ()) + tuple(grid[:: max(1, len(grid) // 5)]):
        assert same(profile(float(value)), em.stats(spec.with_value(kind, float(value)))[0]), (kind, value)


def test_the_pendulum_equation_profiles_as_it_stats(models) -> None:
    em = models["pendulum"]
    spec = em.spec0().with_effect("pendulum_viscous")
    for value in (0.0, 0.004):
        assert same(em.profile(spec, "delay")(value), em.stats(spec.with_value("delay", value))[0])
