"""An input delay beside arm Coulomb friction: whichever stage timed it (the sliding rows, or the stick windows that
re-time the rows' value, latency.retimed), the arm model reported beside it is fitted at the delay reported."""

from __future__ import annotations

import pytest

from benchmarks import suite
from furuta_rt.config import load_rig
from furuta_rt.diagnose import Options, diagnose

FAST = Options(closed_loop=False, max_windows=15)


def test_the_arm_model_is_fitted_at_the_delay_reported(tmp_path) -> None:
    """4 ms of transport delay beside arm Coulomb friction, balancing without excitation (the arm parks in a stick–slip
    cycle): the delay comes out within 20 %, and the arm model (its command path, hence the gain, damping and inertia
    the identification reports) is the one at that delay. Where the breakaways re-timed the sliding rows' value (the
    rows hold brief sticks and can time the delay short), the rows' own value differs from it."""
    rig = load_rig("thesis")
    case = suite.Case("input_delay+arm_coulomb", ("input_delay.delay=0.004", "arm_coulomb.Fc=0.04"), 48, None)
    d = diagnose(suite.generate(case, rig, tmp_path), rig, FAST)
    delay = next(e for e in d.effects if e.name == "input_delay")
    assert delay.source in ("stick windows", "inverse dynamics")
    assert delay.params["delay"] == pytest.approx(0.004, rel=0.2)
    rows = next(r for r in d.equations["arm"].trace if r["candidate"] == "latency (joint)")
    if delay.source == "stick windows":
        assert abs(rows["value"] - delay.params["delay"]) > 0.0002  # re-timed: the rows' own timing differs
    else:
        assert rows["value"] == delay.params["delay"]
    arm = d.equations["arm"].selected
    assert arm.spec.path.delay == delay.params["delay"]
    assert next(e for e in d.effects if e.name == "arm_coulomb").params == arm.params["arm_coulomb"]
