"""What a newcomer's mistakes on the command line get: one line naming the command and the option (argparse's usage
is in ``--help``), the nearest option for a misspelt one, and values in the wrong unit refused by name."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest
from test_reliability_harness import FURUTA_RT, traceback_free

from furuta_rt.config import RigConfig, implausible, load_rig


def furuta(*args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([*FURUTA_RT, *args], capture_output=True, text=True, timeout=timeout)


def one_line(proc: subprocess.CompletedProcess) -> str:
    assert proc.returncode == 2 and traceback_free(proc.stderr), proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    return lines[0]


@pytest.mark.parametrize(("args", "names"), [
    (["run", "--duration", "abc"], ["furuta-rt run: error:", "--duration", "'abc'"]),
    (["run", "--comp", "foo"], ["furuta-rt run: error:", "--comp", "'foo'", "coulomb"]),
    (["run", "--foxglove=abc"], ["furuta-rt run: error:", "--foxglove", "'abc'"]),
    (["run", "--mock", "--port", "/dev/ttyACM0"], ["furuta-rt run: error:", "--port", "--mock"]),
    (["run", "--mokc"], ["furuta-rt run: error:", "--mokc", "did you mean --mock?", "furuta-rt run --help"]),
    (["design", "--jsn"], ["furuta-rt design: error:", "--jsn", "did you mean --json?"]),
    (["bogus"], ["furuta-rt: error:", "'bogus'", "run"]),
])
def test_a_usage_error_is_one_line_naming_the_command_and_the_option(args: list[str], names: list[str]) -> None:
    line = one_line(furuta(*args))
    assert "usage:" not in line
    for name in names:
        assert name in line, line


def test_a_directory_given_as_port_is_one_line() -> None:
    line = one_line(furuta("run", "--port", "/tmp", "--duration", "1", "--no-tui"))
    assert line.startswith("furuta-rt run: error: --port /tmp is a directory") and "Errno" not in line, line


def test_an_angle_limit_in_degrees_is_refused_naming_degrees(tmp_path: Path) -> None:
    thesis = (Path(__file__).resolve().parents[1] / "furuta_rt" / "rigs" / "thesis.toml").read_text()
    rig = tmp_path / "rig.toml"
    rig.write_text(re.sub(r"(?m)^theta_limit = .*$", "theta_limit = 28.6", thesis))
    for command in (["design"], ["run", "--mock", "--duration", "1", "--no-tui"]):
        line = one_line(furuta(*command, "--config", str(rig)))
        assert "safety.theta_limit" in line and "28.6 degrees = 0.4992 rad" in line, line


def _with(rig: RigConfig, **sections: dict) -> RigConfig:
    data = rig.model_dump()
    for name, values in sections.items():
        node = data
        *path, last = name.split("__")
        for part in path:
            node = node[part]
        node[last] = {**node[last], **values}
    return RigConfig.model_validate(data)


@pytest.mark.parametrize(("sections", "key", "hint"), [
    ({"safety": {"phi_limit": 1080.0}}, "safety.phi_limit", "degrees"),
    ({"safety": {"arm_theta": 5.7}}, "safety.arm_theta", "degrees"),
    ({"swing_up": {"catch_theta": 20.0}}, "swing_up.catch_theta", "degrees"),
    ({"compensation__coulomb": {"epsilon": 180.0}}, "compensation.coulomb.epsilon", "degrees/s"),
    ({"compensation__adaptive": {"Fc_max": 150.0}}, "compensation.adaptive.Fc_max", "N cm"),
    ({"actuator": {"limit": 200.0}}, "actuator.limit", "N cm"),
])
def test_every_angle_rate_and_torque_limit_is_checked(sections: dict, key: str, hint: str) -> None:
    thesis = load_rig("thesis")
    assert implausible(thesis) == []
    problems = implausible(_with(thesis, **sections))
    assert len(problems) == 1 and f"key '{key}'" in problems[0] and f"in {hint}?" in problems[0], problems


def test_the_shipped_rigs_are_plausible() -> None:
    for name in ("thesis", "qube_servo2", "macstepien"):
        assert implausible(load_rig(name)) == [], name


def test_a_misspelt_table_names_the_unknown_one_and_the_missing_one(tmp_path: Path) -> None:
    thesis = (Path(__file__).resolve().parents[1] / "furuta_rt" / "rigs" / "thesis.toml").read_text()
    rig = tmp_path / "rig.toml"
    rig.write_text(thesis.replace("[plant]", "[plnt]", 1))
    line = one_line(furuta("design", "--config", str(rig)))
    assert "'plnt' is not a key; did you mean 'plant'?" in line and "'plant' is required and missing" in line, line
    assert "Field required" not in line


def test_an_effect_value_that_is_not_a_number_says_so() -> None:
    from furuta_rt.model.effects import parse_effect_assignment

    with pytest.raises(ValueError, match="the value 'abc' is not a number"):
        parse_effect_assignment("arm_coulomb.Fc=abc")
    with pytest.raises(ValueError, match=re.escape("is not of the form name.param=value")):
        parse_effect_assignment("arm_coulomb=0.3")
    line = one_line(furuta("run", "--mock", "--mock-effect", "arm_coulomb.Fc=abc", "--duration", "1", "--no-tui"))
    assert "the value 'abc' is not a number" in line and "not of the form" not in line, line


def test_help_texts_read_as_english() -> None:
    for command in (["analyze", "limit-cycle"], ["diagnose"], ["replay"], ["convert"], ["run"]):
        text = " ".join(furuta(*command, "--help").stdout.split())
        assert "existing a " not in text and "replace the existing" in text, command


def _hil_mock(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "hil_mock", "--pty", "--duration", "0.3", *args],
                          capture_output=True, text=True, timeout=60)


def test_hil_mock_checks_the_rig_as_run_does_and_config_names_a_rig(tmp_path: Path) -> None:
    thesis = (Path(__file__).resolve().parents[1] / "furuta_rt" / "rigs" / "thesis.toml").read_text()
    cm = tmp_path / "cm.toml"
    cm.write_text(re.sub(r"(?m)^l = .*$", "l = 41.3", thesis))
    for flag in ("--rig", "--config"):  # --config is a rig, as everywhere in furuta-rt
        line = one_line(_hil_mock(flag, str(cm)))
        assert line.startswith("hil-mock: error:") and "plant.l" in line and "41.3 cm = 0.413 m" in line, line
    mock = tmp_path / "mock.toml"
    mock.write_text('rig = "thesis"\n')
    old = _hil_mock("--config", str(mock))  # the old use of --config still works, and says what it did
    assert old.returncode == 0 and traceback_free(old.stderr), old.stderr
    assert "is a mock TOML" in old.stderr and "--mock-config" in old.stderr and "serving on" in old.stdout + old.stderr
    new = _hil_mock("--mock-config", str(mock))
    assert new.returncode == 0 and "note" not in new.stderr, new.stderr


def test_hil_mock_usage_errors_are_one_line_too() -> None:
    line = one_line(subprocess.run([sys.executable, "-m", "hil_mock", "--rate", "abc"], capture_output=True, text=True,
                                   timeout=60))
    assert line.startswith("hil-mock: error:") and "--rate" in line and "'abc'" in line, line
    line = one_line(subprocess.run([sys.executable, "-m", "hil_mock", "--pyt"], capture_output=True, text=True,
                                   timeout=60))
    assert "did you mean --pty?" in line, line
