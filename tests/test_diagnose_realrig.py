"""The first physics of simple real-rig experiments: a free swing's loss (its envelope's shape, the energy fit) and
period, read from recordings simulated with a seed and from the macstepien rig's real free decay; an arm that rests
at zero command while the pendulum pulls it (dry friction, not a dead band), also in a short 50 Hz file; possible
causes with a non-physical sign are never offered."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from benchmarks.suite_realrig import HELD_ARM, driven_recording, square_pulses, swing_recording
from furuta_rt.config import RigConfig, load_rig
from furuta_rt.diagnose import Options, diagnose
from furuta_rt.diagnose.judgement import verdict
from furuta_rt.diagnose.regression.library import PEND, Context
from furuta_rt.diagnose.regression.states import prepare
from furuta_rt.diagnose.stages import armlock, swing
from furuta_rt.diagnose.stages.decay import free_decay
from furuta_rt.io.mapping import load_mapping, read_mapped_csv
from furuta_rt.recording import Recording

REALDATA = Path(__file__).resolve().parents[2] / "shared" / "realdata" / "macstepien-furuta"
FAST = Options(closed_loop=False, max_windows=15)


def _read(rec: Recording, rig: RigConfig) -> tuple[swing.Swing, object]:
    prep = prepare(rec, rig)
    assert swing.is_free_swing(prep, rig)
    decay = free_decay(prep, rig)
    assert decay is not None
    return swing.read(prep, rig, decay.peaks_t, decay.rest_offset), decay


@pytest.fixture(scope="module")
def qube() -> RigConfig:
    return load_rig("qube_servo2")


@pytest.mark.parametrize(("effects", "shape"), [
    (["pendulum_viscous.bp=5e-5"], "exponential"),
    (["pendulum_coulomb.Fc=2e-4"], "linear"),
    (["pendulum_viscous.bp=5e-5", "pendulum_coulomb.Fc=1e-4"], "both"),
])
def test_the_envelope_names_the_loss_law(qube: RigConfig, effects: list[str], shape: str) -> None:
    """Viscous friction leaves an exponential envelope, Coulomb friction a linear one, both a combination — read from
    the turning points alone, at 100 Hz through 2048-count encoders."""
    read, decay = _read(swing_recording(qube, [*effects, HELD_ARM], 100.0), qube)
    assert read.envelope is not None and read.envelope.shape == shape, read.envelope
    others = [v for k, v in read.envelope.loo.items() if k not in (shape, "both")]
    assert all(read.envelope.loo[shape] < 0.5 * v for v in others), read.envelope.loo
    # the energy fit (stages/decay.py) names the same law and sizes it
    assert decay.best == {"exponential": "viscous", "linear": "coulomb"}.get(shape, "both")
    truth = dict(e.split("=") for e in effects)
    best = decay.fits[decay.best]
    if "pendulum_viscous.bp" in truth:
        assert best.bp == pytest.approx(float(truth["pendulum_viscous.bp"]), rel=0.15)
    if "pendulum_coulomb.Fc" in truth:
        assert best.Fc == pytest.approx(float(truth["pendulum_coulomb.Fc"]), rel=0.15)
    assert read.period is not None and not read.period.mismatch, read.period  # the config is the simulated rig


def test_the_period_pins_gravity_torque_over_inertia(qube: RigConfig) -> None:
    """A pendulum 30 % heavier in inertia about its centre than the config says swings slower: the period gives the
    true (ε/α) ratio within its standard error, flagged as a mismatch, and the text says what it cannot tell."""
    true = qube.model_copy(update={"plant": qube.plant.model_copy(update={"J2": 1.3 * qube.plant.J2})})
    read, _ = _read(swing_recording(true, ["pendulum_viscous.bp=3e-5", HELD_ARM], 100.0, seed=4), qube)
    ratio = qube.lumped().alpha / true.lumped().alpha  # ε unchanged
    p = read.period
    assert p is not None and p.mismatch
    assert abs(p.ratio - ratio) < 3 * p.se + 0.005, (p.ratio, ratio, p.se)
    assert p.se < 0.02
    assert "pins this ratio only" in p.text()


def test_config_period_is_the_pendulum_period(qube: RigConfig) -> None:
    """The config's period from energy conservation: 2π√(α/ε) at small amplitude, and the exact pendulum's
    complete-elliptic-integral period at 1 rad (T = 4√(α/ε)·K(sin²(A/2)), 1.0663× the small-angle one)."""
    from furuta_rt.model.plant import FurutaPlant

    p = qube.lumped()
    small = 2 * math.pi * math.sqrt(p.alpha / p.epsilon)
    assert swing.config_period(FurutaPlant(p), 1e-3) == pytest.approx(small, rel=1e-6)
    assert swing.config_period(FurutaPlant(p), 1.0) == pytest.approx(1.0663 * small, rel=2e-4)


def test_a_free_swing_needs_no_command_and_a_still_arm(qube: RigConfig) -> None:
    rec = swing_recording(qube, ["pendulum_viscous.bp=5e-5", HELD_ARM], 100.0, seconds=6.0)
    assert swing.is_free_swing(prepare(rec, qube), qube)
    pushed = Recording(t=rec.t, theta=rec.theta, theta_dot=rec.theta_dot, phi=rec.phi, u=np.full(len(rec.t), 0.5))
    assert not swing.is_free_swing(prepare(pushed, qube), qube)  # 0.5 V of 10 V is a command
    turning = Recording(t=rec.t, theta=rec.theta, theta_dot=rec.theta_dot, phi=0.5 * np.sin(rec.t), u=rec.u)
    assert not swing.is_free_swing(prepare(turning, qube), qube)


def test_the_real_free_decay_of_the_macstepien_rig() -> None:
    """The macstepien rig's own recording (ODrive, 500 Hz, released near upright): the loss needs viscous and
    Coulomb friction both, by the envelope and by the energy fit, and the period agrees with the rig's published
    parameters to within 1 % (what the authors fitted, b2 = 1.79e-5 N m s/rad viscous alone, is the same order as the
    viscous part here)."""
    rig = load_rig("macstepien")
    rec = read_mapped_csv(REALDATA / "hardware_pure_joint1_oscillations.csv", load_mapping("macstepien"))
    read, decay = _read(rec, rig)
    assert read.envelope.shape == "both" and decay.best == "both"
    assert decay.fits["both"].loo_rms < 0.3 * min(decay.fits["viscous"].loo_rms, decay.fits["coulomb"].loo_rms)
    both = decay.fits["both"]
    assert 3e-6 < both.bp < 1.79e-5 * 2 and both.Fc > 10 * both.se_Fc
    assert read.period is not None and not read.period.mismatch
    assert abs(read.period.ratio - 1) < 0.01


def test_a_short_free_swing_is_said_to_be_one(qube: RigConfig) -> None:
    """Four seconds of a heavily damped swing at 50 Hz: too few cycles above the noise to fit a loss per cycle;
    diagnose says so rather than fitting one."""
    rec = swing_recording(qube, ["pendulum_viscous.bp=4e-4", HELD_ARM], 50.0, seconds=4.0, seed=2)
    d = diagnose(rec, qube, FAST)
    assert d.decay is None and swing.TOO_FEW in d.notes, d.notes


def test_no_cause_needs_a_negative_mass() -> None:
    """A remainder that only a pendulum mass of −0.4 × the config's would fit (coefficient 1.4 on its column) is no
    possible cause; the same column at 0.4 (a mass 0.6 × the config's) is one."""
    rig = load_rig("qube_servo2")
    rec = swing_recording(rig, ["pendulum_viscous.bp=5e-5", HELD_ARM], 100.0, seconds=8.0)
    prep = prepare(rec, rig)
    ctx = Context.build(prep, rig, 0.04, 0.02, 0.005)
    column = dict((k, c) for k, _, c in verdict.cause_columns(ctx, [PEND]))["m2"](0.0)[PEND]
    rows = prep.valid.copy()
    rng = np.random.default_rng(0)
    scale = float(np.std(column[rows]))
    draws = 1e-3 * scale * rng.standard_normal((20, int(rows.sum())))

    def causes(a: float) -> list[dict]:
        y = a * column + 1e-3 * scale * rng.standard_normal(len(column))
        return verdict.possible_causes(ctx, {PEND: (y, rows, (1e-3 * scale) ** 2, draws)})

    offered = causes(0.4)
    assert any(c["key"] == "m2" and abs(c["coefficient"] - 0.4) < 0.02 for c in offered), offered
    for c in causes(1.4):
        assert c["key"] in verdict.FIXED_COLUMN_CAUSES or c["coefficient"] < 1.0, c
        assert "× config" not in c["value"] or float(c["value"].split("=")[1].split("×")[0]) > 0, c


STICTION = ["arm_stiction.Fs=0.012", "arm_coulomb.Fc=0.008"]  # N m; the QUBE's motor gives 5 mN m per volt


def test_a_short_50_hz_file_shows_the_arm_locking_at_zero_command(qube: RigConfig) -> None:
    """Six seconds at 50 Hz of square pulses: after each pulse the arm stops and stays at one count while the
    pendulum swings and pulls it. diagnose runs and reports dry friction holding at least a torque that lies below
    the true breakaway (a lower bound: the pendulum's pull never reaches Fs) and is most of it."""
    rec = driven_recording(qube, STICTION, 50.0, 6.0, square_pulses(3.0))
    d = diagnose(rec, qube, FAST)
    lock = d.to_json()["arm_rests"]
    assert lock is not None and lock["verdict"] == "dry friction", lock
    assert 0.5 * 0.012 < lock["held_at_zero_command"] < 1.1 * 0.012, lock
    assert any("dry friction holding" in n for n in d.notes)


def test_a_dead_band_without_friction_never_reads_as_dry_friction(qube: RigConfig) -> None:
    """The same pulses on an arm with a 1 V dead band and viscous friction only: the arm never rests against the
    pendulum's pull, so no dry friction is claimed."""
    rec = driven_recording(qube, ["input_deadzone.width=1.0", "arm_viscous.Fv=2e-4"], 50.0, 6.0,
                           square_pulses(3.0))
    lock = armlock.assess(prepare(rec, qube), qube)
    assert lock is None or lock.verdict != "dry friction", lock


@pytest.mark.parametrize("effects", [["input_deadzone.width=1.0"], ["arm_stiction.Fs=0.006", "arm_coulomb.Fc=0.004"]])
def test_slow_small_sines_leave_dead_band_and_friction_alike(qube: RigConfig, effects: list[str]) -> None:
    """A slow 1.5 V sine: the arm stands still where |u| is small, by a dead band or by friction alike — said as a
    look-alike with the experiments that separate them, whichever is true."""
    rec = driven_recording(qube, effects, 50.0, 8.0, lambda t: 1.5 * math.sin(t))
    lock = armlock.assess(prepare(rec, qube), qube)
    assert lock is not None and lock.verdict == "look-alike", lock
    assert 0.9 < lock.small_command <= 1.5
    assert "look alike" in lock.text() and "zero command with the pendulum swinging" in lock.text()


def test_a_named_dead_band_meets_the_rests_that_need_friction(qube: RigConfig) -> None:
    """A dead band named while the rests at zero command show dry friction is declared as that friction's look-alike;
    with dry friction named too, nothing is added."""
    lock = armlock.assess(prepare(driven_recording(qube, STICTION, 50.0, 6.0, square_pulses(3.0)), qube), qube)
    entries = armlock.declare(lock, ["input_deadzone"], [], "a slow sweep")
    assert len(entries) == 1 and entries[0]["effects"] == ["input_deadzone", "arm_stiction"]
    assert "dead band may be that friction" in entries[0]["reason"]
    assert armlock.declare(lock, ["input_deadzone", "arm_coulomb"], [], "a slow sweep") == []


def test_a_fast_decaying_swing_is_a_loss(qube: RigConfig) -> None:
    """A viscous decay from 1 rad at 50 Hz: its losses shrink fast (a large scatter about their mean) but every cycle
    loses energy — a loss, sized within 10 %, not 'no measurable loss'."""
    read, decay = _read(swing_recording(qube, ["pendulum_viscous.bp=8e-5", HELD_ARM], 50.0, amplitude=1.0, seed=25), qube)
    assert decay.best == "viscous" and decay.fits["viscous"].bp == pytest.approx(8e-5, rel=0.1)
    assert not read.lossless


def test_a_frictionless_swing_names_no_loss(qube: RigConfig) -> None:
    """A swing without pivot friction loses no energy beyond the reading's noise: no pivot friction is named."""
    rec = swing_recording(qube, [HELD_ARM], 100.0, seconds=10.0, seed=16)
    d = diagnose(rec, qube, FAST)
    assert d.decay is not None and d.decay["best"] == "none", d.decay
    assert not {"pendulum_viscous", "pendulum_coulomb"} & set(d.names)
    assert any("no measurable loss" in n for n in d.notes)


def test_a_rest_through_a_pulse_is_read_in_its_parts(qube: RigConfig) -> None:
    """A rest that runs from zero command into a 4 V pulse the friction still holds: its zero-command part is read on its
    own and shows dry friction (read whole, the pulse's 4 V made it a small-command rest: a dead band's look-alike)."""
    rec = driven_recording(qube, ["arm_stiction.Fs=0.015", "arm_coulomb.Fc=0.01"], 100.0, 5.0, square_pulses(4.0), seed=18)
    lock = armlock.assess(prepare(rec, qube), qube)
    assert lock is not None and lock.verdict == "dry friction", lock
    assert 0.5 * 0.015 < lock.at_zero < 1.1 * 0.015


def test_a_two_and_a_half_second_50_hz_file_is_diagnosed_for_what_it_holds(qube: RigConfig) -> None:
    """2.4 s at 50 Hz (120 samples): diagnose runs, says each equation has too few rows to assess, and names nothing it
    cannot support; 1.5 s is refused in one line naming the minimum."""
    from furuta_rt.errors import UserError

    rec = driven_recording(qube, STICTION, 50.0, 2.4, square_pulses(3.0))
    d = diagnose(rec, qube, FAST)
    assert d.effects == []
    assert {v.verdict for v in d.verdicts.values()} == {"not_assessed"}, d.summary
    with pytest.raises(UserError, match="at least 100"):
        diagnose(driven_recording(qube, STICTION, 50.0, 1.5, square_pulses(3.0)), qube, FAST)


def test_one_command_magnitude_leaves_gain_and_dead_band_alike(qube: RigConfig) -> None:
    """±3 V pulses through a 1 V dead band: the arm equation names an input gain (the same column on one magnitude),
    declared with the dead band of (1 − g)·3 V as its look-alike — its width within 10 % of the true 1 V. Pulses of two
    heights through a true gain of 0.7 name the gain with no such look-alike (two magnitudes tell them apart)."""
    rec = driven_recording(qube, ["input_deadzone.width=1.0", "arm_viscous.Fv=2e-4"], 50.0, 6.0, square_pulses(3.0))
    d = diagnose(rec, qube, FAST)
    alike = [a for a in d.ambiguities if a["effects"] == ["input_gain", "input_deadzone"]]
    assert len(alike) == 1, d.ambiguities
    assert alike[0]["alternative"]["params"]["width"] == pytest.approx(1.0, rel=0.1)

    def two_heights(t: float) -> float:
        return square_pulses(3.0)(t) if t % 6.0 < 3.0 else square_pulses(1.5)(t)

    rec = driven_recording(qube, ["input_gain.gain=0.7", "arm_viscous.Fv=2e-4"], 50.0, 12.0, two_heights, seed=3)
    d = diagnose(rec, qube, FAST)
    assert "input_gain" in d.names
    assert not any(set(a["effects"]) == {"input_gain", "input_deadzone"} for a in d.ambiguities), d.ambiguities


def test_a_short_50_hz_swing_of_a_right_config_is_consistent(qube: RigConfig) -> None:
    """5 s of a 0.15 rad free swing at 50 Hz, nothing wrong: at ω·dt ≈ 0.2 the kernel's θ, θ̇ and θ̈ see the swing
    through kernels that differ by (ω·dt)²/12, a residual like a 3 % pendulum-inertia error that the floor must hold
    (it read `unexplained`, J2 ≈ 1.03 × config). A true 10 % inertia error in the same swing still stands above it."""
    def pendulum(inertia: float) -> verdict.EquationVerdict:
        rig = qube.model_copy(update={"plant": qube.plant.model_copy(update={"J2": inertia * qube.plant.J2})})
        return diagnose(swing_recording(rig, [HELD_ARM], 50.0, amplitude=0.15, seconds=5.0), qube, FAST).verdicts[PEND]

    right = pendulum(1.0)
    assert right.verdict == "consistent", right
    wrong = pendulum(1.1)
    assert wrong.verdict == "unexplained" and wrong.residual_nominal > 2 * wrong.noise_floor, wrong


def test_one_step_hides_sliding_friction_in_the_gain() -> None:
    """A 2 V step on a macstepien-shaped arm with Coulomb friction 0.005 N m: the arm slides one way under one command,
    where Fc·sgn(φ̇) is the same column as the gain (read 1 − Fc/(K·2 V) ≈ 0.61 × nominal) — no dry friction is named
    and the notes say why and which recordings separate them. ±V pulses (both ways) get no such note."""
    rig = load_rig("macstepien")
    effects = ["arm_coulomb.Fc=0.005", "arm_viscous.Fv=0.0117"]
    step = driven_recording(rig, effects, 500.0, 3.0, lambda t: 2.0 if t >= 0.5 else 0.0, seed=3)
    d = diagnose(step, rig, FAST)
    gain = {e.name: e.params for e in d.effects}.get("input_gain")
    assert "arm_coulomb" not in d.names and gain is not None, d.names
    k = rig.actuator.Kt / rig.actuator.R  # N m per volt at rest
    assert gain["gain"] == pytest.approx(1 - 0.005 / (2.0 * k), rel=0.05)
    assert any(n.startswith("dry friction cannot be read on this recording") for n in d.notes), d.notes
    pulses = diagnose(driven_recording(rig, effects, 500.0, 6.0, square_pulses(2.0), seed=3), rig, FAST)
    assert not any(n.startswith("dry friction cannot be read") for n in pulses.notes), pulses.notes
