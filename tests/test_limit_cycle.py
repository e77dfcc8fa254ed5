"""Section 4 (describing function) through `furuta-rt analyze limit-cycle --json`, against the thesis'
conclusions and hand formulas; the periodic orbit of the nonlinear loop against long simulation."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from furuta_rt.analysis.describing_function import (
    SECTION4_CASES,
    CoulombRelay,
    analyze_limit_cycle,
    friction_to_arm_velocity,
    num_den,
)
from furuta_rt.analysis.limit_cycle import coulomb_effects
from furuta_rt.analysis.periodic_orbit import (
    IdealLoop,
    OrbitNotFound,
    SampledLoop,
    find_periodic_orbit,
    relative_errors,
    simulate_limit_cycle,
)
from furuta_rt.cli import main
from furuta_rt.controller.controller import design_gains
from furuta_rt.controller.design import characteristic_polynomial
from furuta_rt.model.plant import FurutaPlant


def _cli_json(capsys: pytest.CaptureFixture[str], *args: str) -> dict:
    assert main(["analyze", "limit-cycle", "--json", *args]) == 0
    return json.loads(capsys.readouterr().out)


@pytest.mark.parametrize("name", list(SECTION4_CASES))
def test_thesis_section4_cases(capsys: pytest.CaptureFixture[str], name: str) -> None:
    gains, thesis_says = SECTION4_CASES[name]
    out = _cli_json(capsys, "--gains", ",".join(f"{g:g}" for g in gains), "--fc", "1")
    for key in ("limit_cycle", "frequency_rad_s", "amplitude_phidot", "closed_loop_stable"):
        assert key in out
    assert out["limit_cycle"] is thesis_says
    assert out["thesis_case"]["thesis_says_limit_cycle"] is thesis_says
    assert (out["frequency_rad_s"] is not None) is thesis_says
    if gains == (60.0, 20.0, 10.0, 4.0):
        # a stable limit cycle of a stable loop
        assert out["closed_loop_stable"] and out["limit_cycle_stable"]
        assert out["frequency_rad_s"] == pytest.approx(5.89, abs=0.01)
    if gains[2] == 0.0:
        assert not out["closed_loop_stable"]  # φ is not fed back: a pole at s = 0
    if gains == (60.0, 20.0, 0.0, 1.0):
        # G(0) = −1/l4: the arm drifts at Fc/l4 (thesis: "rotates ... with a constant velocity")
        assert out["stable_except_arm_drift"] and out["drift_velocity"] == pytest.approx(1.0, rel=1e-6)
    if gains == (60.0, 20.0, 0.0, 7.0):
        # the thesis' "limit cycle" case: the frictionless loop itself is unstable with the default rig,
        # and the crossing is an unstable (threshold) limit cycle
        assert not out["stable_except_arm_drift"] and out["limit_cycle_stable"] is False
        assert any(p[0] > 0 for p in out["closed_loop_poles"])
        assert not out["sampled_loop_stable"]


def test_negative_phi_dot_gain_is_unstable_too(thesis_rig) -> None:
    """Neither sign of the 7φ̇ term gives a stable loop: −7 puts a real pole in the right half plane."""
    lc = analyze_limit_cycle(FurutaPlant(thesis_rig.lumped()), [60, 20, 0, -7], 1.0)
    assert not lc.limit_cycle and not lc.stable_but_arm_drift
    assert np.max(lc.closed_loop_poles.real) > 1.0


def test_df_frequency_and_amplitude_match_the_hand_formula(thesis_rig) -> None:
    """Section 4.3, eq. 11: Im G(jω) = 0 at ω0² = (γ l1 − εβ)/ζ, where
    Re G = −(αω0² + ε)/((α l3 − γ l2) ω0² + ε l3); the φ̇ amplitude is C = 4Fc|Re G|/π."""
    p = thesis_rig.lumped()
    a, b, g, e, z = p.alpha, p.beta, p.gamma, p.epsilon, p.zeta
    l1, l2, l3 = 60.0, 20.0, 7.0
    fc = 0.7
    w0 = math.sqrt((g * l1 - e * b) / z)
    re = -(a * w0**2 + e) / ((a * l3 - g * l2) * w0**2 + e * l3)
    lc = analyze_limit_cycle(FurutaPlant(p), [l1, l2, 0.0, l3], fc)
    (pred,) = lc.predictions
    assert pred.omega == pytest.approx(w0, rel=1e-6)
    assert pred.g_real == pytest.approx(re, rel=1e-4)
    assert pred.amplitude_phidot == pytest.approx(4 * fc * abs(re) / math.pi, rel=1e-4)
    # python-control's describing_function_response finds the same intersection
    ((amp, freq),) = lc.python_control_intersections
    assert freq == pytest.approx(w0, rel=1e-4) and amp == pytest.approx(pred.amplitude_phidot, rel=1e-3)


def test_g_is_eq6_closed_with_u_eq_Lx(thesis_rig) -> None:
    """G(s) = s(αs² − ε)/(ζ·charpoly) (section 4.1) with the section-3.2 polynomial of design.py."""
    p = thesis_rig.lumped()
    L = np.array([60.0, 20.0, 10.0, 4.0])
    num, den = num_den(friction_to_arm_velocity(FurutaPlant(p), L))
    np.testing.assert_allclose(den, characteristic_polynomial(p, L), rtol=1e-6)
    np.testing.assert_allclose(num, [p.alpha / p.zeta, 0.0, -p.epsilon / p.zeta, 0.0], rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("l3", [0.5, 1.0, 3.0, 5.0, 6.5, 7.0, 9.0])
def test_section43_limit_cycle_iff_frictionless_loop_unstable(thesis_rig, l3: float) -> None:
    """For u = l1θ + l2θ̇ + l3φ̇ the thesis' limit-cycle condition (α l3 − γ l2)ω0² + ε l3 > 0 is exactly
    the Routh condition for the frictionless loop to be unstable."""
    lc = analyze_limit_cycle(FurutaPlant(thesis_rig.lumped()), [60.0, 20.0, 0.0, l3], 1.0, with_python_control=False)
    assert lc.limit_cycle is (not lc.stable_but_arm_drift)


def test_coulomb_relay_describing_function_is_4fc_over_pi_c() -> None:
    import control

    n = CoulombRelay(0.3)
    amps = np.array([0.1, 1.0, 5.0])
    numeric = control.describing_function(n, amps)  # python-control's numerical Fourier integral
    np.testing.assert_allclose(np.real(numeric), 4 * 0.3 / (math.pi * amps), rtol=1e-3)
    assert n(2.0) == 0.3 and n(-1e-9) == -0.3


def test_default_rig_periodic_orbit_agrees_with_simulation(thesis_rig) -> None:
    """Shooting on the ideal loop (u = L·x, nonlinear plant, Coulomb Fc = 1.1 N m: the reproduction's
    calibrated level) vs a long simulation of that loop; the describing function misses by > 10%."""
    fc = 1.1
    L = design_gains(thesis_rig)
    eff = coulomb_effects(thesis_rig, fc)
    orbit = find_periodic_orbit(IdealLoop(thesis_rig, L, eff))
    sim, _ = simulate_limit_cycle(IdealLoop(thesis_rig, L, eff), duration=40.0, transient=15.0)
    for key, err in relative_errors(orbit.stats, sim).items():
        assert abs(err) < 0.05, key
    assert orbit.stable and orbit.residual < 1e-6 and orbit.stats.stuck_fraction > 0.1
    df = analyze_limit_cycle(FurutaPlant(thesis_rig.lumped()), L, fc).main
    assert df is not None and df.stable
    assert abs(df.period - orbit.stats.period) / orbit.stats.period > 0.1  # the sine assumption misses the stick phases


def test_sampled_loop_orbit_agrees_with_simulation(thesis_rig) -> None:
    """The rig's loop (Bessel path, observer, delay at 500 Hz, no noise) with Coulomb Fc = 0.05 N m."""
    eff = coulomb_effects(thesis_rig, 0.05)
    orbit = find_periodic_orbit(SampledLoop(thesis_rig, None, eff))
    sim, _ = simulate_limit_cycle(SampledLoop(thesis_rig, None, eff), duration=45.0, transient=15.0)
    errs = relative_errors(orbit.stats, sim)
    assert abs(errs["period"]) < 0.05 and abs(errs["amplitude_phi_dot"]) < 0.05 and abs(errs["amplitude_theta"]) < 0.05
    assert orbit.stable
    # the sampled loop oscillates slower than the ideal one (filter and observer lag)
    assert orbit.stats.period > 4.0


def test_no_orbit_when_the_loop_settles(thesis_rig) -> None:
    """60θ + 20θ̇ + φ̇: θ settles while the arm drifts, so there is no θ crossing to shoot on."""
    with pytest.raises(OrbitNotFound):
        find_periodic_orbit(IdealLoop(thesis_rig, [60, 20, 0, 1], coulomb_effects(thesis_rig, 0.5)), max_period=3.0)


def test_cli_orbit_plot_and_errors(capsys: pytest.CaptureFixture[str], tmp_path) -> None:
    png = tmp_path / "nyquist.png"
    out = _cli_json(capsys, "--fc", "0.05", "--orbit", "--plot", str(png))
    assert png.stat().st_size > 1000
    rep = out["periodic_orbit"]["ideal"]
    assert abs(rep["orbit_vs_simulation"]["period"]) < 0.05
    assert rep["orbit"]["period_s"] == pytest.approx(3.67, rel=0.02)
    assert out["frequency_rad_s"] == pytest.approx(2.16, rel=0.01)
    assert main(["analyze", "limit-cycle", "--fc", "-1"]) == 2
    assert main(["analyze", "limit-cycle", "--gains", "1,2,3"]) == 2
    assert main(["analyze", "limit-cycle", "--plot", str(tmp_path / "x.pdf")]) == 2
    err = capsys.readouterr().err
    assert "--fc" in err and "--gains" in err and ".png" in err


def test_nyquist_png_is_wide_titled_with_its_g_and_axes_named(tmp_path, thesis_rig) -> None:
    """`analyze limit-cycle --plot`: ≥ 1000 px wide, the axes say which G(jω) and its unit, the title the
    transfer function, the rig, the law and Fc."""
    import struct

    from matplotlib.figure import Figure

    from furuta_rt.analysis.figures import G_NAME, nyquist_axes

    out = tmp_path / "nyquist.png"
    assert main(["analyze", "limit-cycle", "--plot", str(out), "--fc", "0.3"]) == 0
    width, height = struct.unpack(">II", out.read_bytes()[16:24])  # the PNG's IHDR
    assert width >= 1000 and height >= 600
    ax = Figure().subplots()
    lc = analyze_limit_cycle(FurutaPlant(thesis_rig.lumped()), design_gains(thesis_rig), 0.3)
    nyquist_axes(ax, lc, "thesis rig")
    assert ax.get_xlabel() == "Re G(jω) (rad/s per N m)" and ax.get_ylabel() == "Im G(jω) (rad/s per N m)"
    assert "φ̇(s)/F(s)" in G_NAME
