"""The sensor noise measured from the recording (furuta_rt.diagnose.judgement.noise_model) and the null recordings with noise
the config does not state (benchmarks.suite_null)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from benchmarks import suite_null as sn
from furuta_rt.config import load_rig
from furuta_rt.diagnose import Options, diagnose
from furuta_rt.diagnose.judgement import noise_model
from furuta_rt.diagnose.regression.states import prepare
from furuta_rt.model.sensors import BesselPath, quantise
from furuta_rt.recording import Recording


def _recording(adc: tuple[float, float], pre_psd: float, seed: int = 3, duration: float = 30.0) -> Recording:
    """A slow pendulum motion seen through the thesis rig's Bessel path with known noise."""
    rig = load_rig("thesis")
    dt = 1.0 / 500
    n = round(duration / dt)
    t = np.arange(n) * dt
    rng = np.random.default_rng(seed)
    bessel = BesselPath(rig.sensors.bessel_cutoff)
    w = 2 * np.pi * 0.7
    theta, theta_dot = 0.02 * np.sin(w * t), 0.02 * w * np.cos(w * t)
    if pre_psd:
        y, yd = noise_model.prefiltered(n, dt, bessel, pre_psd, rng)
        theta, theta_dot = theta + y, theta_dot + yd
    s = rig.sensors
    theta = quantise(theta + adc[0] * rng.standard_normal(n), s.theta_rad_per_count)
    theta_dot = quantise(theta_dot + adc[1] * rng.standard_normal(n), s.theta_dot_rad_s_per_count)
    return Recording(t=t, theta=theta, theta_dot=theta_dot, phi=np.zeros(n), u=np.zeros(n))


@pytest.mark.parametrize(("adc", "pre"), [((3e-4, 4e-3), 8e-10), ((2e-4, 2e-3), 0.0), ((6e-4, 6e-3), 8e-10)])
def test_noise_levels_recovered_from_the_spectra(adc: tuple[float, float], pre: float) -> None:
    rig = load_rig("thesis")
    est = noise_model.estimate(prepare(_recording(adc, pre), rig), rig)
    assert est.source == "recording"
    assert est.theta_adc == pytest.approx(adc[0], rel=0.1)
    assert est.theta_dot_adc == pytest.approx(adc[1], rel=0.1)
    if pre:
        assert math.sqrt(est.prefilter_psd) == pytest.approx(math.sqrt(pre), rel=0.1)
    else:  # no pre-filter source: at most a trace of one (its θ rms under a tenth of the ADC's)
        assert math.sqrt(est.prefilter_psd * 2 * 8.0) < 0.1 * adc[0]


def test_config_disagreement_is_said_and_agreement_is_not() -> None:
    rig = load_rig("thesis")
    loud = noise_model.estimate(prepare(_recording((6e-4, 6e-3), 8e-10), rig), rig)
    assert "× the config's" in loud.note
    calm = noise_model.estimate(prepare(_recording((2e-4, 2e-3), 0.0), rig), rig)
    assert calm.note and "× the config's" not in calm.note


def test_a_recording_without_a_band_above_the_dynamics_keeps_the_config() -> None:
    rig = load_rig("thesis")
    rec = _recording((3e-4, 4e-3), 8e-10)
    slow = Recording(t=rec.t[::10], theta=rec.theta[::10], theta_dot=rec.theta_dot[::10], phi=rec.phi[::10],
                     u=rec.u[::10])  # 50 Hz: Nyquist below the band
    est = noise_model.estimate(prepare(slow, rig), rig)
    assert est.source == "config" and est.theta_adc == rig.sensors.theta_noise


def test_prefilter_null_reads_consistent() -> None:
    """Nothing concealed, θ noise entering before the Bessel filter (which the config cannot state): the pendulum
    equation is consistent (with the config's white ADC noise as the floor it was called unexplained)."""
    case = next(c for c in sn.CASES if c.noise == "prefilter" and not c.held_out)
    d = diagnose(sn.simulate(case, 20.0), load_rig("thesis"), Options(closed_loop=False)).to_json()
    assert d["equations"]["pendulum"]["verdict"] == "consistent", d["summary"]
    assert d["effects"] == []
    assert any(n.startswith("sensor noise measured") for n in d["notes"])


def test_practical_size_moves_an_effect_below_it_out_and_refits(monkeypatch: pytest.MonkeyPatch) -> None:
    """The size of a found arm viscous is its torque Fv·φ̇ (rms) over the command's (the arm's torque scale), as
    physics says; with the threshold above that size the effect is listed below practical size, not reported, and
    the arm equation is refitted without it."""
    import furuta_rt.diagnose.judgement.practical as practical
    from benchmarks import suite_independent as ind
    from furuta_rt.diagnose.stages import practical_size

    case = next(c for c in ind.CASES if c.name == "arm_viscous")
    rec = ind.simulate(case, 20.0)
    rig = load_rig("thesis")
    D = diagnose(rec, rig, Options(closed_loop=False))
    assert "arm_viscous" in D.names and D.below_practical == []
    ctx, em, r = D.context, D.models["arm"], D.equations["arm"]
    size = practical.sizes(ctx, em, r.selected)["arm_viscous"]
    fv = next(f.params["Fv"] for f in D.effects if f.name == "arm_viscous")
    rows = em.row_mask
    expect = fv * np.sqrt(np.mean(ctx.arm.phi_dot[rows] ** 2)) / np.sqrt(np.mean(ctx.command_torque(ctx.base_path)[rows] ** 2))
    assert size == pytest.approx(expect, rel=0.05)
    assert size > practical.PRACTICAL_SHARE
    monkeypatch.setattr(practical, "PRACTICAL_SHARE", 1.5 * size)
    res = dict(D.equations)
    kept, below = practical_size.split(ctx, D.models, res, list(D.effects), 0)
    assert "arm_viscous" not in [f.name for f in kept]
    assert [b["name"] for b in below] == ["arm_viscous"] and below[0]["size"] == pytest.approx(size)
    assert "arm_viscous" not in res["arm"].selected.spec.effects
    assert "below practical size" in practical.describe(below)


def test_a_swing_up_floor_holds_only_the_residual_paths_own_error(tmp_path) -> None:
    """A QUBE swing-up of the independent DC simulator with pendulum damping 1e-5 N m s: the floor's processing error is
    that of the path the residual takes (eq. 4 on F's states, then K), not of eq. 4 on the wide states, whose bias on
    the spin is tens of % of the torque scale (floors of 64 % on the arm and 34 % on the pendulum, above the nominal
    residual itself, hid the damping as 'below practical size'). Both floors stay under the nominal residual."""
    from benchmarks import suite_independent_dc as dc

    case = next(c for c in dc.cases() if c.name == "qube/swingup damping")
    rec = dc.generate(case, 10.0, tmp_path)
    d = diagnose(rec, load_rig(case.shape), Options(closed_loop=False, max_windows=15))
    arm, pend = d.verdicts["arm"], d.verdicts["pendulum"]
    assert arm.noise_floor < 0.1 * arm.residual_nominal, arm
    assert pend.noise_floor < 0.5 * pend.residual_nominal, pend
