"""The shipped rigs against their published sources, and the realistic proof group of `diagnose` end to end."""

from __future__ import annotations

import math

import pytest

from furuta_rt.config import load_rig, rig_from_dict
from furuta_rt.errors import UserError


def test_qube_servo2_is_quansers_published_rig() -> None:
    """QUBE-Servo 2 user manual: the arm's inertia about the motor axis is Jr = mr Lr²/12 plus the rotor (4.0e-6)
    and the hub (mh rh²/2); the pendulum's about its pivot mp Lp²/3; the motor 0.042 N m/A over 8.4 Ω."""
    rig = load_rig("qube_servo2")
    mr, Lr, mp, Lp = 0.095, 0.085, 0.024, 0.129
    J_about_pivot = mr * Lr**2 / 12 + 4.0e-6 + 0.0106 * 0.0111**2 / 2
    assert rig.plant.arm_inertia == pytest.approx(J_about_pivot, rel=0.01)
    p = rig.lumped()
    assert p.beta == pytest.approx(J_about_pivot + mp * Lr**2, rel=0.01)  # the pendulum's mass at the arm's tip
    assert p.alpha == pytest.approx(mp * Lp**2 / 3, rel=1e-3)
    assert p.gamma == pytest.approx(mp * Lr * Lp / 2, rel=1e-3)
    assert p.epsilon == pytest.approx(mp * 9.81 * Lp / 2, rel=1e-3)
    a = rig.actuator
    assert (a.kind, a.Kt, a.R, a.Ke) == ("dc_motor", 0.042, 8.4, 0.042)
    assert rig.sensors.bessel_cutoff is None  # encoders on both joints
    assert rig.sensors.encoder_counts_per_rev == 2048
    assert rig.sensors.theta_rad_per_count == pytest.approx(2 * math.pi / 2048)


def test_macstepien_is_its_yaml() -> None:
    """pendulum_parameters.yaml of macstepien/furuta_pendulum: Kt = 0.103375 N m/A, R = 16 Ω (6.46 mN m/V)."""
    rig = load_rig("macstepien")
    a = rig.actuator
    assert a.Kt / a.R == pytest.approx(0.103375 / 16.0, rel=1e-9)
    assert a.Ke == pytest.approx(0.00130899693899575)
    pl = rig.plant
    assert (pl.m1, pl.l1, pl.L1, pl.J1) == (0.040466, 0.05415, 0.093525, 5.96237099e-4)
    assert (pl.m2, pl.l2, pl.L2, pl.J2) == (0.009801, 0.096608, 0.129, 1.4790595e-5)
    assert rig.sensors.bessel_cutoff is None


def test_thesis_rig_is_appendix_c() -> None:
    pl = load_rig("thesis").plant
    assert (pl.r, pl.l, pl.M, pl.m, pl.Jp, pl.J) == (0.235, 0.413, 0.01, 0.02, 0.0009, 0.05)


def test_bessel_cutoff_none_in_toml_and_bad_values() -> None:
    base = {"plant": {"parametrisation": "thesis", "l": 0.4, "r": 0.2, "M": 0.01, "m": 0.02, "Jp": 1e-3, "J": 0.05}}
    assert rig_from_dict({**base, "sensors": {"bessel_cutoff": "None"}}).sensors.bessel_cutoff is None
    assert rig_from_dict({**base, "sensors": {"bessel_cutoff": 80.0}}).sensors.bessel_cutoff == 80.0
    with pytest.raises(UserError, match="bessel_cutoff"):
        rig_from_dict({**base, "sensors": {"bessel_cutoff": "off"}})
    with pytest.raises(UserError, match="bessel_cutoff"):
        rig_from_dict({**base, "sensors": {"bessel_cutoff": -1.0}})
