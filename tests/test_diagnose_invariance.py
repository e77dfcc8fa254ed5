"""`diagnose` at any amplitude and independent of the angles' coordinates (issue 14, items 3 and 4).

Large motions: synthetic swing-ups and large swings of the QUBE-Servo 2 and the macstepien rig, voltage-driven, with
encoders on both joints and the parameters set here (not the shipped files'). Invariance: the same recording with the
arm's encoder 52 turns further on, the pendulum angle shifted by a turn or wrapped at ±π.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from benchmarks import suite
from furuta_rt.config import load_rig, rig_from_dict
from furuta_rt.diagnose import Options, diagnose
from furuta_rt.diagnose.regression.library import ARM, CANDIDATES, Context
from furuta_rt.diagnose.regression.selection import EquationModel, Thresholds
from furuta_rt.diagnose.regression.states import GaussianFilter, canonical_angles, prepare
from furuta_rt.diagnose.stages.stickslip import assess
from furuta_rt.model.rig import RigModel
from furuta_rt.recording import Recording
from furuta_rt.sim.compiled import fast_simulator

FAST = Options(closed_loop=False, max_windows=15)
RIGS = Path(__file__).resolve().parent.parent / "furuta_rt" / "rigs"

# The rigs' geometry from their files, the parameters that matter here set explicitly: the arm inertia J1 + m1 l1²
# (QUBE-Servo 2: 1.04e-4 kg m², Quanser's Jr about the pivot plus the pendulum-less hub; macstepien: 7.12e-4),
# the motor (Kt, R, Ke), encoders on both joints (no analog θ path), no sensor noise beyond the encoders' counts.
RIG_PARAMS = {
    "qube_servo2": {"J": 1.04e-4, "Kt": 0.042, "R": 8.4, "Ke": 0.042, "counts": 2048, "limit": 10.0},
    "macstepien": {"J": 7.12e-4, "Kt": 0.103375, "R": 16.0, "Ke": 0.0013089969, "counts": 8192, "limit": 12.0},
}


def make_rig(name: str, arm_inertia: float):
    """The rig ``name`` with the arm inertia ``arm_inertia`` (through l1) and RIG_PARAMS' motor and encoders."""
    with (RIGS / f"{name}.toml").open("rb") as fh:
        d = tomllib.load(fh)
    p, q = d["plant"], RIG_PARAMS[name]
    p["l1"] = math.sqrt((arm_inertia - p["J1"]) / p["m1"])
    d["actuator"].update(kind="dc_motor", Kt=q["Kt"], R=q["R"], Ke=q["Ke"], limit=q["limit"])
    d["sensors"].update(bessel_cutoff=None, theta_noise=0.0, theta_dot_noise=0.0, encoder_counts_per_rev=q["counts"])
    d.pop("effects", None)
    rig = rig_from_dict(d)
    assert rig.plant.arm_inertia == pytest.approx(arm_inertia, rel=1e-12)
    return rig


def large_motion(rig, kind: str, seconds: float = 16.0, seed: int = 0) -> Recording:
    """``kind`` = "swing": energy pumping from hanging (u ∝ (E_up − E)·sgn(θ̇ cos θ), the arm kept near its start),
    the pendulum swinging up to ±1.4 rad from hanging; "sine": three open-loop sine voltages around the pendulum's
    natural frequency, the pendulum turning over. The command of tick k acts from tick k + 1 (the rig's
    command_delay_ticks = 1); θ and φ quantised to the encoder's counts."""
    model = RigModel.from_config(rig)
    rate = rig.control.rate_hz
    sim = fast_simulator(model, rate, 5000.0, seed=seed, x0=(math.pi - 0.05, 0.0, 0.0, 0.0))
    n = round(seconds * rate)
    lsb = 2 * math.pi / rig.sensors.encoder_counts_per_rev
    p = model.plant.p
    lim = rig.actuator.limit
    rng = np.random.default_rng(seed)
    freqs = math.sqrt(p.epsilon / p.alpha) / (2 * math.pi) * np.array([0.7, 1.0, 1.3])
    phases = rng.uniform(0, 2 * math.pi, 3)
    t = np.arange(n) / rate
    th, ph, u = np.empty(n), np.empty(n), np.empty(n)
    for k in range(n):
        th[k], ph[k] = round(sim.theta / lsb) * lsb, round(sim.phi / lsb) * lsb
        if kind == "swing":
            energy = 0.5 * p.alpha * sim.theta_dot**2 + p.epsilon * math.cos(sim.theta)
            v = 4.0 * (p.epsilon - energy) / p.epsilon * np.sign(sim.theta_dot * math.cos(sim.theta))
            v -= 1.5 * sim.phi + 0.1 * sim.phi_dot
        else:
            v = 0.35 * lim * float(np.sum(np.sin(2 * math.pi * freqs * t[k] + phases)))
        u[k] = float(np.clip(v, -0.6 * lim, 0.6 * lim))
        sim.advance()
        sim.set_command(u[k])
    return Recording(t=t, theta=th, phi=ph, u=u)


@pytest.fixture(scope="module")
def swings():
    out = {}
    for name in RIG_PARAMS:
        rig = make_rig(name, RIG_PARAMS[name]["J"])
        out[name] = (rig, {kind: large_motion(rig, kind) for kind in ("swing", "sine")})
    return out


def test_large_motions_are_recordings_of_large_motions(swings) -> None:
    """The recordings are what the tests below claim: swings of more than ±1 rad from hanging, pendulum turnovers."""
    for _, recs in swings.values():
        sw, si = recs["swing"], recs["sine"]
        assert np.max(np.abs(sw.theta - math.pi)) > 1.0 and np.ptp(si.theta) > 4 * math.pi


@pytest.mark.parametrize("name", list(RIG_PARAMS))
@pytest.mark.parametrize("kind", ["swing", "sine"])
def test_large_motion_with_the_true_parameters_has_no_effect(swings, name, kind) -> None:
    """Eq. 4 evaluated on the lightly smoothed states, the products filtered (signals.States): no spurious effect.
    (Before: on the QUBE swing-up arm viscous + pendulum viscous, on its turnovers input gain 1.35 + J 2.2× the true.)"""
    rig, recs = swings[name]
    d = diagnose(recs[kind], rig, FAST)
    assert d.names == []
    assert d.equations["arm"].location.relative_rms < 0.02
    assert d.equations["pendulum"].location.relative_rms < 0.01


@pytest.mark.parametrize(("name", "factor"), [("qube_servo2", 2.2), ("qube_servo2", 0.7), ("macstepien", 1.4)])
@pytest.mark.parametrize("kind", ["swing", "sine"])
def test_large_motion_finds_the_arm_inertia(swings, name, kind, factor) -> None:
    """The config's arm inertia off by ``factor`` (the shipped QUBE file had 2.2×): the true J within 5 %, alone."""
    _, recs = swings[name]
    true_j = RIG_PARAMS[name]["J"]
    d = diagnose(recs[kind], make_rig(name, true_j * factor), FAST)
    assert d.names == ["arm_inertia"]
    assert d.effects[0].params["J"] == pytest.approx(true_j, rel=0.05)
    assert d.fit["augmented"] < d.fit["nominal"]


def test_fine_kernel_noise_is_removed_by_the_outer_kernel(swings) -> None:
    """The encoder's quantisation through the 5 ms kernel's second derivative is large (≈ 10 rad/s² on a 2048-count
    encoder), but it enters eq. 4 linearly and the outer kernel removes it: the composed kernel's noise gain for φ̈ is
    no larger than the wide one's alone, and the nominal residual of a still recording stays at the noise floor."""
    dt, lsb = 0.002, 2 * math.pi / 2048
    fine, outer = GaussianFilter.build(0.005, dt), GaussianFilter.build(0.03, dt)
    both = GaussianFilter.composed(outer, fine)
    q = lsb / math.sqrt(12.0)
    fine_noise = q * float(np.linalg.norm(fine.kernels[2]))
    assert fine_noise > 5.0  # rad/s²: the fine kernel alone does not remove it
    composed_noise, outer_noise = (q * float(np.linalg.norm(k.kernels[2])) for k in (both, outer))
    assert 0.9 * outer_noise < composed_noise <= outer_noise  # 0.11 rad/s²: no amplification by F
    assert both.width == pytest.approx(math.hypot(0.03, 0.005), rel=0.01)
    # quantised white noise on a still pendulum: the pendulum residual (all of eq. 4's products) is noise, no bias
    rig, _ = swings["qube_servo2"]
    rng = np.random.default_rng(1)
    n = 5000
    th = math.pi + np.round(0.002 * rng.standard_normal(n) / lsb) * lsb
    rec = Recording(t=np.arange(n) * dt, theta=th, phi=np.zeros(n), u=np.zeros(n))
    prep = prepare(rec, rig)
    ctx = Context.build(prep, rig, 0.03, 0.05, 0.005)
    r = ctx.pend_residual[prep.valid]
    assert abs(float(np.mean(r))) < 0.05 * float(np.std(r)) + 1e-9


# ------------------------------------------------------------------------------------------------ invariance
def shifted(rec: Recording, dphi: float = 0.0, dtheta: float = 0.0, wrap: bool = False) -> Recording:
    th = rec.theta + dtheta
    if wrap:
        th = np.angle(np.exp(1j * th))  # θ as an atan2 would give it, in (−π, π]
    return dataclasses.replace(rec, theta=th, phi=rec.phi + dphi)


def same(a, b) -> None:
    """The same effects with the same parameters (1e-6 relative), the same residuals and prediction."""
    assert a.names == b.names
    for ea, eb in zip(a.effects, b.effects, strict=True):
        assert ea.params == pytest.approx(eb.params, rel=1e-6, abs=1e-12)
    for eq in ("arm", "pendulum"):
        assert a.equations[eq].location.relative_rms == pytest.approx(b.equations[eq].location.relative_rms, rel=1e-6)
    assert a.fit["augmented"] == pytest.approx(b.fit["augmented"], rel=1e-4)


@pytest.fixture(scope="module")
def thesis_rig():
    return load_rig("thesis")


@pytest.fixture(scope="module")
def balancing(thesis_rig, tmp_path_factory):
    """A cable spring and a null case of the suite, 30 s each."""
    cache = tmp_path_factory.mktemp("suite")
    cases = {
        "spring": suite.Case("arm_spring", ("arm_spring.k=0.01", "arm_spring.phi0=0.2"), 27, "sine", 30.0),
        "null": suite.Case("null", (), 3, "sine", 30.0),
    }
    return {k: suite.generate(c, thesis_rig, cache) for k, c in cases.items()}


def test_a_cable_spring_is_found_whatever_the_encoders_turn_count(thesis_rig, balancing) -> None:
    """The arm's encoder 52 turns further on (and the pendulum's angle a turn off): the same spring, its rest angle in
    the travel's own turn (signals.canonical_angles). Before, the spring's admissibility |φ0| < 2π depended on the
    absolute count."""
    rec = balancing["spring"]
    a = diagnose(rec, thesis_rig, FAST)
    b = diagnose(shifted(rec, 2 * math.pi * 52, -2 * math.pi), thesis_rig, FAST)
    assert "arm_spring" in a.names
    spring = next(e for e in a.effects if e.name == "arm_spring").params
    assert spring["k"] == pytest.approx(0.01, rel=0.2) and spring["phi0"] == pytest.approx(0.2, abs=0.05)
    same(a, b)


def test_null_balancing_is_invariant(thesis_rig, balancing) -> None:
    rec = balancing["null"]
    a = diagnose(rec, thesis_rig, FAST)
    assert a.names == []
    same(a, diagnose(shifted(rec, -2 * math.pi * 52, 2 * math.pi), thesis_rig, FAST))


def test_a_wrapped_pendulum_angle_gives_the_same_diagnosis(swings) -> None:
    """θ recorded wrapped at ±π (the swing-up crosses it), or a turn off: the same result as the continuous angle,
    with the arm inertia off so that there is an effect to compare."""
    _, recs = swings["qube_servo2"]
    cfg = make_rig("qube_servo2", 1.3 * RIG_PARAMS["qube_servo2"]["J"])
    rec = recs["swing"]
    wrapped = shifted(rec, wrap=True)
    assert np.max(np.abs(np.diff(wrapped.theta))) > 6.0  # it does wrap
    a = diagnose(rec, cfg, FAST)
    assert a.names == ["arm_inertia"]
    same(a, diagnose(wrapped, cfg, FAST))
    same(a, diagnose(shifted(rec, 2 * math.pi * 3, 2 * math.pi), cfg, FAST))


def test_canonical_angles() -> None:
    """θ unwrapped and shifted by whole turns (hanging ends at π, upright at 0), φ's travel centred within ±π."""
    t = np.linspace(0, 10, 5001)
    theta = math.pi + 2.5 * np.sin(t)
    for k in (-3, 0, 5):
        th, ph = canonical_angles(np.angle(np.exp(1j * (theta + 2 * math.pi * k))), 0.3 * np.sin(t) + 2 * math.pi * k)
        np.testing.assert_allclose(th, theta, atol=1e-9)
        np.testing.assert_allclose(ph, 0.3 * np.sin(t), atol=1e-9)
    th, _ = canonical_angles(0.1 * np.sin(t) - 4 * math.pi, t)
    np.testing.assert_allclose(th, 0.1 * np.sin(t), atol=1e-9)
    # prepare() keeps what it took away, for the checks of the angles' units (θ = 180 at rest reads as degrees)
    rig = load_rig("thesis")
    rec = Recording(t=t, theta=theta + 2 * math.pi * 28, phi=0.3 * np.sin(t) - 2 * math.pi * 3, u=np.zeros_like(t))
    prep = prepare(rec, rig)
    assert prep.turns == pytest.approx((2 * math.pi * 28, -2 * math.pi * 3))
    np.testing.assert_allclose(prep.as_recorded().theta_f, rec.theta, atol=1e-9)
    # a rig whose config declares a spring keeps the encoder's own turns
    _, ph = canonical_angles(theta, t + 2 * math.pi * 4, keep_phi=True)
    np.testing.assert_allclose(ph, t + 2 * math.pi * 4)


def test_spring_admissible_only_where_the_travel_allows_one(thesis_rig) -> None:
    """A cable spring: k > 0, the arm's travel less than a turn, the rest angle inside the travel."""
    spring = CANDIDATES["arm_spring"]
    assert spring.plausible({"k": 0.01, "phi0": 0.2}, thesis_rig, (-1.0, 1.0))
    assert not spring.plausible({"k": -0.01, "phi0": 0.2}, thesis_rig, (-1.0, 1.0))
    assert not spring.plausible({"k": 0.01, "phi0": 1.5}, thesis_rig, (-1.0, 1.0))  # centre outside the travel
    assert not spring.plausible({"k": 0.01, "phi0": 0.2}, thesis_rig, (-3.5, 3.5))  # the arm turns a whole turn


# ------------------------------------------------------------------------------------------------ stick windows
@pytest.fixture(scope="module")
def sticking(thesis_rig, tmp_path_factory):
    cache = tmp_path_factory.mktemp("window-cases")
    case = suite.Case("arm_stiction", ("arm_coulomb.Fc=0.05", "arm_stiction.Fs=0.08"), 58, None, 30.0)
    return suite.generate(case, thesis_rig, cache)


def test_stick_stage_runs_without_coulomb_selected_first(thesis_rig, sticking) -> None:
    """With no Coulomb friction in the model (say the regression could not tell it from a deadzone or a gain), the
    stick windows decide on a dry friction at the sliding rows' provisional level, then on the breakaway above it."""
    prep = prepare(sticking, thesis_rig)
    ctx = Context.build(prep, thesis_rig, 0.03, 0.05, 0.005)
    em = EquationModel(ctx, ARM, Thresholds())
    level = em.evaluate_with(em.spec0(), "arm_coulomb").params["arm_coulomb"]["Fc"]  # as stick_windows.provisional_coulomb
    assert level == pytest.approx(0.05, rel=0.1)
    stage = assess(thesis_rig, {}, prep, ctx.fine, Thresholds(), lambda d: None, coulomb=level)
    assert stage is not None
    assert set(stage.added) == {"arm_coulomb", "arm_stiction"}
    assert stage.added["arm_coulomb"]["Fc"] == level
    assert stage.fits["arm_coulomb"].gain > 0.5
    assert stage.added["arm_stiction"]["Fs"] == pytest.approx(0.08, rel=0.2)
    assert assess(thesis_rig, {}, prep, ctx.fine, Thresholds(), lambda d: None) is None  # no level at all: no stage
