"""The held-out prediction metric and the prediction gate of `diagnose` (furuta_rt.diagnose.judgement.verify, .gate)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from benchmarks.suite import reference_signal
from furuta_rt.config import load_rig
from furuta_rt.diagnose import Options, diagnose
from furuta_rt.diagnose.engine import Found
from furuta_rt.diagnose.judgement import verify
from furuta_rt.diagnose.regression.library import ARM, PEND, Context
from furuta_rt.diagnose.regression.selection import EquationModel
from furuta_rt.diagnose.regression.states import prepare
from furuta_rt.diagnose.stages import gate
from furuta_rt.model.effects import Effects
from furuta_rt.model.rig import RigModel
from furuta_rt.recording import Recording
from furuta_rt.sim.closed_loop import run_closed_loop
from furuta_rt.sim.compiled import fast_simulator


@pytest.fixture(scope="module")
def rig():
    return load_rig("thesis")


def balancing(rig, effects: dict, seed: int, duration: float = 25.0) -> Recording:
    """Closed-loop balancing with an arm-reference sine (as the diagnosis suite records it)."""
    n = round(duration * rig.control.rate_hz)
    ref = reference_signal("sine", n, rig.control.rate_hz, seed)
    rec = run_closed_loop(rig, duration, effects=Effects.model_validate(effects), seed=seed, reference=ref)
    rec.extra["phi_ref"] = ref
    return rec


@pytest.fixture(scope="module")
def coulomb(rig):
    return balancing(rig, {"arm_coulomb": {"Fc": 0.06}}, seed=12)


@pytest.fixture(scope="module")
def null(rig):
    return balancing(rig, {}, seed=3)


def test_horizon_follows_the_unstable_pole(rig) -> None:
    """The horizon is E_FOLDS e-folding times of eq. 6's unstable pole (√(ε/α)-like for the thesis rig)."""
    lam = verify.unstable_pole(rig)
    A, _ = RigModel.from_config(rig).plant.linearize()
    assert lam == pytest.approx(max(np.linalg.eigvals(A).real))
    assert 2.0 < lam < 20.0  # a pendulum of a few tenths of a metre: e-folds in tens to hundreds of ms
    h = verify.horizon_ticks(rig, 0.002)
    assert h * 0.002 == pytest.approx(min(max(verify.E_FOLDS / lam, 0.1), 0.5), abs=0.002)


def test_injected_effect_predicts_better(rig, coulomb) -> None:
    """Arm Coulomb friction injected: found, kept by the gate, and the held-out prediction improves significantly,
    over windows spread across the whole recording, each predicted with parameters fitted away from it."""
    d = diagnose(coulomb, rig, Options(closed_loop=False))
    assert d.names == ["arm_coulomb"] and d.not_predictive == []
    f = d.fit
    assert f["verdict"] == "improved" and f["paired_t"] >= verify.T_DIFFERENT
    assert f["augmented"] < 0.5 * f["nominal"]
    assert f["nominal_diverged"] == f["augmented_diverged"] == 0
    times = np.asarray(f["window_times_s"])
    assert len(times) == f["windows"] >= 30
    assert times.min() < 3.0 and times.max() > 20.0  # the whole recording, not its last 30 %
    assert f["folds"] == gate.N_FOLDS
    folds = f["train_params"]  # one parameter set per fold, each fitted without the fold: close to the truth, not equal
    fcs = [p["arm_coulomb"]["Fc"] for p in folds]
    assert all(abs(fc - 0.06) < 0.006 for fc in fcs) and len(set(fcs)) == gate.N_FOLDS


def _context(rec: Recording, rig) -> tuple[Context, dict[str, EquationModel]]:
    prep = prepare(rec, rig)
    ctx = Context.build(prep, rig, 0.03, 0.05, 0.005)
    opts = Options()
    return ctx, {eq: EquationModel(ctx, eq, opts.thresholds) for eq in (ARM, PEND)}


def test_gate_moves_an_effect_that_predicts_worse(rig, null) -> None:
    """A deliberately wrong effect (a 0.15 rad θ offset on a rig without one) fed through the gate is moved to
    not_predictive with its numbers; a harmless one (a tiny arm spring) is kept: drop on evidence, keep without."""
    from furuta_rt.diagnose.stages.equations import select_equation as _select

    ctx, _ = _context(null, rig)
    opts = Options()
    ems, res = {}, {}
    for eq in (ARM, PEND):
        ems[eq], res[eq] = _select(ctx, eq, opts)
    assert not any(r.selected.spec.effects for r in res.values())  # the null recording: nothing selected
    wrong = Found("theta_offset", PEND, {"offset": 0.15}, {}, 10.0, 0.12, source="given")
    harmless = Found("arm_spring", ARM, {"k": 1e-5, "phi0": 0.0}, {}, 3.0, 0.001, source="given")
    notes: list[str] = []
    out = gate.run(ctx, ems, res, [wrong, harmless], opts, notes)
    assert [f.name for f in out.found] == ["arm_spring"]
    (moved,) = out.not_predictive
    assert moved["name"] == "theta_offset" and moved["equation"] == PEND and moved["params"] == {"offset": 0.15}
    p = moved["prediction"]
    assert p["nrmse_with"] > p["nrmse_without"] * (1 + gate.MIN_RISE) and p["paired_t"] >= gate.T_HARM
    assert "lowers the inverse-dynamics residual by 12.0 %" in moved["reason"]
    assert f"{p['nrmse_without']:.3f} → {p['nrmse_with']:.3f}" in moved["reason"]
    # what is left predicts like the nominal model (the spring is tiny), so it is not called an improvement
    assert verify.compare(out.nominal, out.augmented)["verdict"] == "unchanged"


def test_a_diverging_prediction_is_reported_as_diverging(rig, null) -> None:
    """A model that makes the open-loop prediction leave the data beyond the linear region is "diverges", never an
    improvement, whatever its NRMSE (the error of a diverged window is counted at the bounds, not its blow-up)."""
    prep = prepare(null, rig)
    fine = prep.states(0.005)
    h = verify.horizon_ticks(rig, prep.dt)
    starts, _ = verify.informative_starts(prep, h, 20)
    nominal = verify.predict(rig, Effects(), prep, fine, starts, h)
    wrong = verify.predict(rig, Effects.model_validate({"input_gain": {"gain": 20.0}}), prep, fine, starts, h)
    assert nominal.diverged.sum() == 0
    assert wrong.diverged.sum() >= 3
    assert verify.compare(nominal, wrong)["verdict"] == "diverges"
    assert verify.compare(wrong, nominal)["verdict"] == "improved"  # the other way round: fewer divergences, better
    # a diverged window's error is bounded by the divergence bounds
    bound = 0.5 * (verify.THETA_DIVERGED / wrong.scale_theta + verify.PHI_DIVERGED / wrong.scale_phi)
    assert np.all(wrong.per_window <= bound + 1e-9)


def swing_then_still(rig, active: float = 8.0, still: float = 17.0) -> Recording:
    """A pendulum hanging and swung by the arm for ``active`` s, then everything at rest (a heavily damped rig with
    the command off): like a swing-up followed by a still tail, from the shared simulator."""
    eff = Effects.model_validate({"pendulum_viscous": {"bp": 0.01}, "arm_viscous": {"Fv": 0.2}})
    sim = fast_simulator(RigModel.from_config(rig, eff), rig.control.rate_hz, 2000.0, seed=1, x0=(math.pi - 0.3, 0, 0, 0))
    n = round((active + still) * rig.control.rate_hz)
    cols = {k: np.empty(n) for k in ("t", "theta", "theta_dot", "phi", "u")}
    for k in range(n):
        t = k / rig.control.rate_hz
        u = 0.3 * np.sin(2 * np.pi * 1.1 * t) * np.sin(2 * np.pi * 0.13 * t) if t < active else 0.0
        m = sim.measure()
        for key, v in zip(cols, (m.t, m.theta, m.theta_dot, m.phi, u), strict=True):
            cols[key][k] = v
        sim.set_command(u)
        sim.advance()
    return Recording(t=cols["t"], theta=cols["theta"], phi=cols["phi"], u=cols["u"], theta_dot=cols["theta_dot"])


def test_windows_come_from_the_informative_part(rig) -> None:
    """With a long still tail, the windows are spread over the part where the arm, pendulum or command move."""
    rec = swing_then_still(rig)
    prep = prepare(rec, rig)
    h = verify.horizon_ticks(rig, prep.dt)
    starts, candidates = verify.informative_starts(prep, h, 40)
    t = prep.t[starts]
    assert candidates > 80 and 20 <= len(starts) <= 40
    assert t.max() < 11.0  # none in the still tail (the motion dies out within ~2 s of the command stopping)
    assert t.min() < 1.0 and t.max() > 7.0  # and spread over the whole active part
    act = verify.window_activity(prep, np.asarray(starts), h)
    assert np.all(act[:, 0] > 3 * prep.phi_lsb)  # the arm moves in every chosen window
