"""Rig configuration: shipped rigs load, bad values are refused with a one-line message."""

from __future__ import annotations

import pytest

from furuta_rt.cli import main
from furuta_rt.config import SHIPPED_RIGS, load_rig
from furuta_rt.errors import UserError
from furuta_rt.model.effects import Effects, effects_from_assignments

THESIS_PLANT = '[plant]\nparametrisation="thesis"\nl=0.413\nr=0.235\nM=0.01\nm=0.02\nJp=0.0009\nJ=0.05\n'


@pytest.mark.parametrize("name", SHIPPED_RIGS)
def test_shipped_rigs_load(name: str) -> None:
    rig = load_rig(name)
    assert rig.name == name
    assert rig.lumped().zeta > 0


def test_macstepien_lumped_parameters() -> None:
    p = load_rig("macstepien").lumped()
    # α = J2 + m2 l2², γ = m2 L1 l2, ε = m2 g l2 from pendulum_parameters.yaml
    assert p.alpha == pytest.approx(1.4790595e-5 + 0.009801 * 0.096608**2)
    assert p.gamma == pytest.approx(0.009801 * 0.093525 * 0.096608)
    assert p.epsilon == pytest.approx(0.009801 * 9.81 * 0.096608)


@pytest.mark.parametrize(
    ("text", "fragment"),
    [
        (THESIS_PLANT.replace("M=0.01", "M=-0.01"), "plant.M"),
        (THESIS_PLANT + "[sensors]\nbessel_cutoff = 0\n", "sensors.bessel_cutoff"),
        (THESIS_PLANT + "[control]\nrate_hz = 500\nfoo = 1\n", "control.foo': unknown key"),
        ('[plant]\nparametrisation="thesis"\nl=0.4\n', "needs r, M, m, Jp, J"),
        (THESIS_PLANT + "[effects.arm_coulomb]\nFc = -1\n", "effects.arm_coulomb.Fc"),
        ("[plant\n", "not valid TOML"),
    ],
)
def test_bad_config_is_one_line_error(tmp_path, text: str, fragment: str) -> None:
    cfg = tmp_path / "rig.toml"
    cfg.write_text(text)
    with pytest.raises(UserError) as err:
        load_rig(cfg)
    msg = str(err.value)
    assert fragment in msg and "\n" not in msg


def test_missing_config_via_cli_exits_2(capsys) -> None:
    assert main(["design", "--config", "/no/such/rig.toml"]) == 2
    err = capsys.readouterr().err
    assert "does not exist" in err and "Traceback" not in err and err.count("\n") == 1


def test_effect_assignments() -> None:
    eff = effects_from_assignments(["arm_coulomb.Fc=0.3", "arm_spring.k=0.02", "arm_spring.phi0=0.1"])
    assert eff.present() == {"arm_coulomb": {"Fc": 0.3}, "arm_spring": {"k": 0.02, "phi0": 0.1}}
    with pytest.raises(ValueError, match="unknown effect"):
        effects_from_assignments(["arm_colomb.Fc=0.3"])
    with pytest.raises(ValueError, match="has no parameter"):
        effects_from_assignments(["arm_coulomb.F=0.3"])
    with pytest.raises(ValueError, match=r"Fs .* must be >="):
        Effects.model_validate({"arm_coulomb": {"Fc": 0.3}, "arm_stiction": {"Fs": 0.1}})
