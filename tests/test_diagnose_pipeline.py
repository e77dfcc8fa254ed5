"""The diagnose pipeline (engine.PIPELINE over stages.state.State): a stage reads one State and returns a new one,
never changing the one it was given; a new stage is one function and one entry in the list."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from furuta_rt.config import load_rig
from furuta_rt.diagnose import Options, engine
from furuta_rt.diagnose.regression.library import ARM, PEND
from furuta_rt.diagnose.stages.findings import Found
from furuta_rt.diagnose.stages.start import start
from furuta_rt.diagnose.stages.state import State
from furuta_rt.model.effects import Effects
from furuta_rt.sim.closed_loop import run_closed_loop

FAST = Options(closed_loop=False, max_windows=10)


@pytest.fixture(scope="module")
def rig():
    return load_rig("thesis")


@pytest.fixture(scope="module")
def recording(rig):
    """8 s of balancing with a concealed arm Coulomb friction and a reference that moves the arm."""
    t = np.arange(int(8.0 * rig.control.rate_hz)) / rig.control.rate_hz
    return run_closed_loop(rig, 8.0, effects=Effects.model_validate({"arm_coulomb": {"Fc": 0.004}}), seed=2,
                           reference=np.where(t % 4.0 < 2.0, 0.3, -0.3))


def snapshot(s: State) -> tuple:
    """What a stage must leave as it found it: the fields' identities and the findings' values."""
    return (tuple(id(getattr(s, f.name)) for f in dataclasses.fields(s)), [dataclasses.asdict(f) for f in s.found],
            dict(s.res), list(s.notes), {eq: len(r.trace) for eq, r in s.res.items()})


def test_state_operations_return_new_states_and_freeze_what_they_hold(rig, recording) -> None:
    s0 = start(recording, rig, FAST)
    f = Found("arm_bias", ARM, {"tau": 0.01}, {"tau": 0.001}, 10.0, 0.1)
    s1 = s0.add(f).noted("a remark")
    assert s0.found == () and s1.found == (f,) and s1.notes[-1] == "a remark" and len(s1.notes) == len(s0.notes) + 1
    assert s1.drop(["arm_bias"]).found == () and s1.found == (f,)
    s2 = s1.with_(res={"x": 1}, ambiguities=[{"effects": ["arm_bias", "theta_offset"]}],
                  lookalikes=[{"reported": "arm_bias"}, {"reported": "input_gain"}])
    with pytest.raises(TypeError):
        s2.res["y"] = 2  # type: ignore[index]
    assert isinstance(s2.ambiguities, tuple)
    s3 = s2.forget(["arm_bias"])
    assert s3.ambiguities == () and [a["reported"] for a in s3.lookalikes] == ["input_gain"]
    assert len(s2.ambiguities) == 1 and len(s2.lookalikes) == 2
    with pytest.raises(dataclasses.FrozenInstanceError):
        s3.found = ()  # type: ignore[misc]


def test_no_stage_changes_the_state_it_is_given_and_a_new_stage_is_one_entry(rig, recording, monkeypatch) -> None:
    """Every stage of PIPELINE run on a recording with a concealed friction: each returns a State and leaves its input
    as it was; a stage appended to PIPELINE runs last and what it notes reaches the report."""
    seen: list[str] = []

    def checked(stage):
        def run(s: State) -> State:
            before = snapshot(s)
            out = stage(s)
            assert isinstance(out, State), stage.__module__
            assert snapshot(s) == before, f"{stage.__module__} changed the State it was given"
            seen.append(stage.__module__.rsplit(".", 1)[-1])
            return out
        return run

    def extra(s: State) -> State:
        return s.noted(f"extra stage: {len(s.found)} effects, verdicts for {sorted(s.verdicts)}")

    monkeypatch.setattr(engine, "PIPELINE", tuple(checked(st) for st in (*engine.PIPELINE, extra)))
    d = engine.diagnose(recording, rig, FAST)
    assert seen[0] == "equations" and seen[-1] == "test_diagnose_pipeline" and len(seen) == len(engine.PIPELINE)
    assert d.notes[-1] == f"extra stage: {len(d.effects)} effects, verdicts for {sorted([ARM, PEND])}"
    assert "arm_coulomb" in d.names
