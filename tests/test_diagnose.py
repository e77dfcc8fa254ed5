"""`furuta-rt diagnose` on a small subset of the concealed-effect suite, its signal path and its CLI."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from benchmarks import suite
from furuta_rt.cli import main
from furuta_rt.config import load_rig
from furuta_rt.diagnose import Options, diagnose
from furuta_rt.diagnose.judgement.verify import quiet
from furuta_rt.diagnose.regression.states import GaussianFilter, prepare
from furuta_rt.io.csv import write_csv
from furuta_rt.model.plant import FurutaPlant
from furuta_rt.recording import Recording
from furuta_rt.sim.closed_loop import run_closed_loop

FAST = Options(closed_loop=False, max_windows=15)


@pytest.fixture(scope="module")
def rig():
    return load_rig("thesis")


@pytest.fixture(scope="module")
def recordings(rig, tmp_path_factory):
    """The CI subset of the suite, shortened to 30 s each (generated once per test run)."""
    cache = tmp_path_factory.mktemp("suite")
    out = {}
    for case in suite.quick_cases():
        short = dataclasses.replace(case, duration=30.0)
        out[case.name] = (short, suite.generate(short, rig, cache))
    return out


def test_kernel_is_exact_for_a_held_input() -> None:
    """K*φ̈ from samples (second differences through the Gaussian) equals K applied to the held acceleration."""
    dt, n = 0.002, 4000
    rng = np.random.default_rng(0)
    a = np.cumsum(rng.standard_normal(n)) * 0.1
    v = np.concatenate([[0.0], np.cumsum(a * dt)])[:n]
    phi = np.concatenate([[0.0], np.cumsum(v[:-1] * dt + 0.5 * a[:-1] * dt * dt)])
    f = GaussianFilter.build(0.02, dt)
    inner = slice(100, -100)
    np.testing.assert_allclose(f.apply(phi, 2)[inner], f.apply_held(a, 0.0)[inner], rtol=0, atol=1e-9 * np.abs(a).max())
    # the held kernel integrates to one and shifts with the lag
    m0, w = f.hold_kernel(0.002)
    assert w.sum() == pytest.approx(1.0, abs=1e-12)
    centre = np.sum((np.arange(len(w)) + m0) * dt * w)
    assert centre == pytest.approx(0.002 + dt / 2, abs=1e-9)


def test_inverse_dynamics_residual_vanishes_on_true_states(rig) -> None:
    """With the true states (no quantisation, no noise) eq. 4 through the kernel balances the held command
    to about 1e-6 of its size (docs/DIAGNOSE.md, "One kernel for both sides"): measured 1.04–1.11e-6 for
    seeds 3–5 at σ = 30 ms. What is left is eq. 4's nonlinear terms evaluated on the smoothed states
    (f(K*x) ≠ K*f(x)), not the kernel's integration (exact to 1e-9 above): it shrinks with the kernel,
    2.0e-7 at σ = 10 ms."""
    rec = run_closed_loop(rig, 6.0, seed=3)
    x = rec.extra
    inner = slice(200, -200)
    plant = FurutaPlant(rig.lumped())

    def residuals(sigma: float) -> tuple[float, float]:
        f = GaussianFilter.build(sigma, rec.dt)
        th, ph, thd = x["true_theta"], x["true_phi"], x["true_theta_dot"]
        tp, ta = plant.inverse_dynamics(f.apply(th), f.apply(thd), f.apply(ph, 1), f.apply(thd, 1), f.apply(ph, 2))
        held = f.apply_held(rec.u, rig.control.command_delay_ticks * rec.dt)
        return float(np.std((ta - held)[inner]) / np.std(held[inner])), float(np.std(tp[inner]))

    arm, pendulum = residuals(0.03)
    assert arm < 1.5e-6
    assert pendulum < 2e-8  # N m; the pendulum row's torque scale is ε·θ ≈ 1e-3 N m here
    narrow, _ = residuals(0.01)
    assert narrow < 0.3 * arm


def test_bessel_path_is_inverted(rig) -> None:
    """θ reconstructed from the filtered θ_f, θ̇_f matches the true θ (the 50 rad/s path lags ~27 ms)."""
    rec = run_closed_loop(quiet(rig), 6.0, seed=4, x0=(0.1, 0.0, 0.0, 0.0))
    s = prepare(rec, quiet(rig)).states(0.01)
    truth = GaussianFilter.build(0.01, rec.dt).apply(rec.extra["true_theta"])
    inner = slice(100, 1500)  # the recovery from θ = 0.1 rad
    err = np.std((s.theta - truth)[inner])
    lag_err = np.std((GaussianFilter.build(0.01, rec.dt).apply(rec.theta) - truth)[inner])
    assert err < 0.1 * lag_err


def test_null_case_reports_no_effect(rig, recordings) -> None:
    _, rec = recordings["null"]
    d = diagnose(rec, rig, FAST)
    assert d.names == []
    assert d.fit["nominal"] == d.fit["augmented"]
    assert "consistent with the nominal model" in d.located


def test_arm_coulomb_found_with_its_level(rig, recordings) -> None:
    case, rec = recordings["arm_coulomb"]
    d = diagnose(rec, rig, FAST)
    assert d.names == ["arm_coulomb"]
    fc = case.injected["arm_coulomb"]["Fc"]
    assert d.effects[0].params["Fc"] == pytest.approx(fc, rel=0.2)
    assert d.fit["augmented"] < d.fit["nominal"]
    assert "arm equation" in d.located and "sgn(φ̇)" in d.located


def test_theta_offset_found_in_the_pendulum_equation(rig, recordings) -> None:
    case, rec = recordings["theta_offset"]
    d = diagnose(rec, rig, FAST)
    assert d.names == ["theta_offset"]
    assert d.effects[0].equation == "pendulum"
    assert d.effects[0].params["offset"] == pytest.approx(case.injected["theta_offset"]["offset"], rel=0.2)
    # its look-alike (a cable spring) is told apart: it would act in the other equation
    assert any(set(a["effects"]) == {"theta_offset", "arm_spring"} for a in d.lookalikes)


def test_delay_and_gain_pair_found(rig, recordings) -> None:
    case, rec = recordings["input_delay+input_gain"]
    d = diagnose(rec, rig, FAST)
    found = {e.name: e.params for e in d.effects}
    alternatives = {a["alternative"]["name"]: a["alternative"]["params"] for a in d.ambiguities}
    assert found["input_delay"]["delay"] == pytest.approx(0.005, rel=0.2)
    gain = found.get("input_gain") or alternatives.get("input_gain")
    assert gain is not None and abs(gain["gain"] - 0.9) < 0.2 * 0.1
    s = suite.score(case, d.to_json(), d.seconds)
    assert s.false == []


@pytest.fixture(scope="module")
def window_cases(rig, tmp_path_factory):
    """Arm stiction, Coulomb friction alone (both without excitation: the arm parks in a stick–slip cycle) and a torque
    limit that clips only the square wave's steps, 30 s each."""
    cache = tmp_path_factory.mktemp("window-cases")
    cases = {
        "stiction": suite.Case("arm_stiction", ("arm_coulomb.Fc=0.05", "arm_stiction.Fs=0.08"), 58, None, 30.0),
        "coulomb": suite.Case("arm_coulomb", ("arm_coulomb.Fc=0.03",), 11, None, 30.0),
        "saturation": suite.Case("input_saturation", ("input_saturation.limit=0.5",), 57, "square", 30.0),
    }
    return {k: (c, suite.generate(c, rig, cache)) for k, c in cases.items()}


def test_stiction_breakaway_torque_is_found(rig, window_cases) -> None:
    """Eq. 2: the arm sticks until the held torque exceeds Fs = 0.08, slides against Fc = 0.05. The regression finds
    the sliding level, the stick windows the breakaway torque, and the held-out fit improves."""
    _, rec = window_cases["stiction"]
    d = diagnose(rec, rig, FAST)
    found = {e.name: e.params for e in d.effects}
    assert set(found) == {"arm_coulomb", "arm_stiction"}
    assert found["arm_coulomb"]["Fc"] == pytest.approx(0.05, rel=0.05)
    assert found["arm_stiction"]["Fs"] == pytest.approx(0.08, rel=0.2)
    assert next(e for e in d.effects if e.name == "arm_stiction").source == "stick windows"
    assert "stays stuck until it holds Fs" in d.located
    assert d.fit["augmented"] < d.fit["nominal"]
    assert d.stick is not None and d.stick.fits["arm_stiction"].gain > 0.5
    # the Effects vocabulary takes it back: the simulator sticks at the breakaway torque the tool reports
    assert d.found_effects().arm_stiction.Fs == found["arm_stiction"]["Fs"]


def test_coulomb_friction_alone_gets_no_stiction(rig, window_cases) -> None:
    """With Fs = Fc the arm breaks away exactly when the command exceeds Fc: the stick windows add nothing."""
    _, rec = window_cases["coulomb"]
    d = diagnose(rec, rig, FAST)
    assert d.names == ["arm_coulomb"]
    assert d.stick is not None and not d.stick.added and len(d.stick.windows) >= 8


def test_the_rigs_own_effects_are_part_of_the_nominal_model(rig, window_cases) -> None:
    """A rig config that lists arm Coulomb friction: at the right level nothing is missing; at a wrong one the tool
    reports the corrected total (the value to put in the config), not the difference."""
    from furuta_rt.model.effects import effects_from_assignments

    _, rec = window_cases["coulomb"]  # arm_coulomb.Fc = 0.03
    right = rig.model_copy(update={"effects": effects_from_assignments(["arm_coulomb.Fc=0.03"])})
    d = diagnose(rec, right, FAST)
    assert d.names == []
    assert "consistent with the nominal model" in d.located
    wrong = rig.model_copy(update={"effects": effects_from_assignments(["arm_coulomb.Fc=0.02"])})
    d = diagnose(rec, wrong, FAST)
    assert d.names == ["arm_coulomb"]
    assert d.effects[0].params["Fc"] == pytest.approx(0.03, rel=0.05)
    assert d.fit["augmented"] < d.fit["nominal"]


def test_torque_limit_hidden_from_the_regression_is_found(rig, window_cases) -> None:
    """The clipped commands are the square wave's steps, which start from rest (rows the regression leaves out); the
    arm's motion after them shows the limit."""
    _, rec = window_cases["saturation"]
    d = diagnose(rec, rig, FAST)
    found = {e.name: e.params for e in d.effects}
    assert set(found) == {"input_saturation"}
    assert found["input_saturation"]["limit"] == pytest.approx(0.5, rel=0.2)
    assert d.fit["augmented"] < d.fit["nominal"]


def test_cli_diagnoses_a_default_rig_csv_without_config(recordings, tmp_path) -> None:
    _, rec = recordings["arm_coulomb"]
    path = tmp_path / "run.csv"
    write_csv(rec, path)
    out = tmp_path / "d.json"
    report = tmp_path / "report"
    assert main(["diagnose", str(path), "--json", str(out), "--report", str(report)]) == 0
    d = json.loads(out.read_text())
    assert {"effects", "fit", "located"} <= set(d)
    assert {"metric", "nominal", "augmented", "verdict", "nominal_diverged", "augmented_diverged", "windows"} <= set(d["fit"])
    assert [e["name"] for e in d["effects"]] == ["arm_coulomb"]
    assert set(d["effects"][0]) == {"name", "params"} and set(d["effects"][0]["params"]) == {"Fc"}
    assert isinstance(d["located"], str) and d["located"]
    assert d["rig"] == "thesis"
    assert (report / "summary.md").exists() and (report / "residuals.png").exists()


@pytest.mark.parametrize(
    ("content", "needle"),
    [
        (None, "does not exist"),
        ("t,theta,u\n0,0,0\n0.002,0,0\n", "missing column"),
        ("t,theta,phi,u\n" + "".join(f"{k * 0.002},0,0,0\n" for k in range(50)), "at least 100"),
        ("t,theta,phi,u\n" + "".join(f"{k * 0.002},{'nan' if k % 3 else 0},0,0\n" for k in range(1400)), "non-finite values"),
    ],
)
def test_bad_input_is_one_line_exit_2(tmp_path, capsys, content, needle) -> None:
    path = tmp_path / "bad.csv"
    if content is not None:
        path.write_text(content)
    assert main(["diagnose", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and needle in err and "Traceback" not in err


def test_too_short_recording_is_refused(rig) -> None:
    from furuta_rt.errors import UserError

    t = np.arange(300) * 0.002
    rec = Recording(t=t, theta=np.zeros(300), phi=np.zeros(300), u=np.zeros(300))
    with pytest.raises(UserError, match="needs at least"):
        diagnose(rec, rig, FAST)


def test_free_decay_tells_viscous_and_coulomb_pivot_friction_apart() -> None:
    """A simulated free swing with both kinds of pivot friction: the energy lost per cycle needs both, and the
    fitted values come back (eq. 1 and viscous laws of furuta_rt.model.friction)."""
    from furuta_rt.diagnose.stages.decay import free_decay
    from furuta_rt.diagnose.stages.swing import is_free_swing
    from furuta_rt.model.effects import effects_from_assignments
    from furuta_rt.model.rig import RigModel
    from furuta_rt.sim.compiled import fast_simulator

    rig = load_rig("thesis")
    rig = quiet(rig).model_copy(update={"sensors": quiet(rig).sensors.model_copy(update={"bessel_cutoff": None})})
    eff = effects_from_assignments(["pendulum_viscous.bp=2e-4", "pendulum_coulomb.Fc=3e-4", "arm_coulomb.Fc=0.5"])
    sim = fast_simulator(RigModel.from_config(rig, eff), 500.0, 5000.0, x0=(math.pi - 1.5, 0.0, 0.0, 0.0))
    n = 25 * 500
    cols = np.empty((n, 3))
    lsb = 2 * math.pi / 8192  # an encoder on the pendulum (the ADC path of the thesis rig ends at ±π)
    for k in range(n):
        cols[k] = (sim.t, round(sim.theta / lsb) * lsb, sim.measure().phi)
        sim.advance()
    rec = Recording(t=cols[:, 0], theta=cols[:, 1], phi=cols[:, 2], u=np.zeros(n))
    prep = prepare(rec, rig)
    assert is_free_swing(prep, rig)
    r = free_decay(prep, rig)
    assert r is not None and r.best == "both"
    assert r.fits["both"].bp == pytest.approx(2e-4, rel=0.15)
    assert r.fits["both"].Fc == pytest.approx(3e-4, rel=0.15)
    assert r.fits["both"].loo_rms < 0.5 * min(r.fits["viscous"].loo_rms, r.fits["coulomb"].loo_rms)
    d = diagnose(rec, rig, FAST)
    assert {"pendulum_viscous", "pendulum_coulomb"} <= set(d.names)
    assert not any(set(a["effects"]) == {"pendulum_viscous", "pendulum_coulomb"} for a in d.ambiguities)


def test_theta_filter_option() -> None:
    from furuta_rt.cli.diagnose import with_theta_filter
    from furuta_rt.errors import UserError

    rig = load_rig("thesis")
    assert with_theta_filter(rig, "none").sensors.bessel_cutoff is None
    assert with_theta_filter(rig, "80").sensors.bessel_cutoff == 80.0
    with pytest.raises(UserError, match="theta-filter"):
        with_theta_filter(rig, "fast")


def test_a_log_is_diagnosed_on_its_balancing_stretch() -> None:
    from furuta_rt.diagnose.stages.start import balancing_span

    t = np.arange(10.0)
    rec = Recording(t=t, theta=t, phi=t, u=t, extra={"balancing": np.array([0, 0, 1, 1, 1, 0, 1, 1, 0, 0.0])})
    notes: list[str] = []
    assert list(balancing_span(rec, notes).t) == [2.0, 3.0, 4.0]
    assert "balancing stretch" in notes[0]
    assert balancing_span(Recording(t=t, theta=t, phi=t, u=t), []).t is t
