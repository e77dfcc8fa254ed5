"""Other rigs' CSVs through a column mapping: the eight macstepien recordings load with sane ranges and
the project's sign conventions; sparse rows, wrapping, overrides and errors on synthetic files."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from furuta_rt.config import load_rig
from furuta_rt.errors import UserError
from furuta_rt.io.mapping import load_mapping, read_mapped_csv
from furuta_rt.io.recordings import read_recording
from furuta_rt.model.rig import RigModel
from furuta_rt.sim.compiled import fast_simulator

REALDATA = Path(__file__).resolve().parents[2] / "shared" / "realdata" / "macstepien-furuta"
STEPS = {"01": 0.1, "0575": 0.575, "2V": 2.0, "3V": 3.0, "4V": 4.0, "5V": 5.0, "6V": 6.0}


def macstepien(name: str):
    return read_mapped_csv(REALDATA / f"hardware_{name}.csv", load_mapping("macstepien"))


def test_the_realdata_is_there() -> None:
    assert len(list(REALDATA.glob("hardware_*.csv"))) == 8


def test_free_decay_goes_from_upright_to_hanging() -> None:
    rec = macstepien("pure_joint1_oscillations")
    assert abs(rec.duration - 40.3) < 0.1 and rec.theta_dot is None
    assert np.allclose(np.diff(rec.t), 0.002)  # resampled to the rig's 500 Hz
    assert abs(rec.theta[0]) < 0.01  # released near upright (θ = 0)
    assert abs(abs(rec.theta[-1]) - math.pi) < 0.01  # rests hanging (±π)
    assert np.all(rec.u == 0.0)  # the file has no input column
    assert np.ptp(rec.phi) < 0.02  # the arm nearly still (README: ~0.014 rad)
    assert np.max(np.abs(np.diff(rec.theta))) < 0.2  # one continuous curve, no 2π jumps
    swing = np.abs(rec.theta[rec.t > 30] - rec.theta[-1])
    assert swing.max() < 0.3  # the swing has decayed


@pytest.mark.parametrize("name", list(STEPS))
def test_step_responses(name: str) -> None:
    rec = macstepien(f"step_response_{name}")
    volts = STEPS[name]
    assert np.allclose(np.diff(rec.t), 0.002) and rec.duration > 3.0
    assert set(np.unique(rec.u).tolist()) == {0.0, volts}
    assert abs(abs(rec.theta[0]) - math.pi) < 0.1  # starts hanging
    k = int(np.argmax(rec.u != 0))
    assert np.all(rec.u[k:] == volts)  # a step, held to the end
    moving = np.flatnonzero(np.abs(rec.phi - rec.phi[0]) > 0.005)
    assert moving[0] >= k - 1 and rec.t[moving[0]] - rec.t[k] < 0.03  # the arm moves within 30 ms of the step
    assert rec.phi[-1] - rec.phi[k] > 10.0  # a positive voltage turns φ positive
    assert np.all(np.abs(np.diff(rec.theta)) < 0.3)


def test_step_input_moved_back_when_its_first_message_was_missed() -> None:
    rec = macstepien("step_response_3V")
    assert any("moved back to the arm's motion onset" in n for n in rec.meta["notes"])  # type: ignore[union-attr]
    assert abs(rec.t[int(np.argmax(rec.u != 0))] - 0.240) < 0.01
    rec = macstepien("step_response_2V")  # here the first message is in the file: left alone
    assert rec.meta["notes"] == [] and abs(rec.t[int(np.argmax(rec.u != 0))] - 2.742) < 0.003


def test_sign_convention_matches_the_plant() -> None:
    """From hanging, a positive arm command swings θ − π with the same sign as φ in eq. 4 (simulated
    macstepien rig), and the mapped hardware data does the same (the coupling sign γ cos θ < 0 at π)."""
    rig = load_rig("macstepien")
    sim = fast_simulator(RigModel.from_config(rig), 500.0, 5000.0, x0=(math.pi, 0.0, 0.0, 0.0))
    sim.set_command(2.0)
    sim.advance(25)
    ratio_sim = (sim.theta - math.pi) / sim.phi
    rec = macstepien("step_response_2V")
    k = int(np.argmax(rec.u != 0))
    j = k + 25  # 50 ms after the step
    ratio_real = (rec.theta[j] - rec.theta[k]) / (rec.phi[j] - rec.phi[k])
    assert ratio_sim > 0.5 and ratio_real > 0.5
    assert abs(ratio_real - ratio_sim) < 0.25


def write_ros_csv(path: Path, rows: list[list[str]]) -> Path:
    header = "__time,/effort/data,/js/stamp,/js/arm,/js/pend"
    path.write_text(header + "\n" + "\n".join(",".join(r) for r in rows) + "\n")
    return path


def synthetic_mapping(tmp_path: Path, extra: str = "") -> Path:
    p = tmp_path / "map.toml"
    p.write_text(
        'name = "synthetic"\n[rows]\nselect = "/js/stamp"\n[t]\nsource = "/js/stamp"\n'
        '[theta]\nsource = "/js/pend"\nscale = -1.0\noffset = "pi"\nwrap = "pi"\n'
        '[phi]\nsource = "/js/arm"\n[u]\nsource = "/effort/data"\ninitial = 0.0\n' + extra
    )
    return p


def test_sparse_rows_forward_fill_and_wrap(tmp_path: Path) -> None:
    csv = write_ros_csv(tmp_path / "ros.csv", [
        ["0.000", "", "10.000", "1.0", "0.0"],
        ["0.001", "", "10.002", "1.1", "0.1"],
        ["0.002", "3.0", "", "", ""],  # the input topic's row: not a sample
        ["0.003", "", "10.004", "1.2", "-0.1"],
        ["0.004", "", "10.006", "1.3", "3.0"],
    ])
    rec = read_mapped_csv(csv, load_mapping(synthetic_mapping(tmp_path)))
    assert np.allclose(rec.t, [0.0, 0.002, 0.004, 0.006]) and rec.meta["t_start"] == 10.0
    assert rec.u.tolist() == [0.0, 0.0, 3.0, 3.0]
    assert rec.phi.tolist() == [1.0, 1.1, 1.2, 1.3]
    # θ = π − θ_theirs wrapped into (−π, π]: 0 → π, 0.1 → π − 0.1, −0.1 → −π + 0.1, 3 → π − 3
    assert np.allclose(rec.theta, [math.pi, math.pi - 0.1, -math.pi + 0.1, math.pi - 3.0])
    assert np.all(rec.theta > -math.pi) and np.all(rec.theta <= math.pi)


def test_overrides_resampling_and_torque(tmp_path: Path) -> None:
    rows = [[f"{i * 0.003:.3f}", "", f"{i * 0.003:.3f}", f"{0.01 * i:.3f}", "0.0"] for i in range(40)]
    rows.insert(4, ["0.0095", "2.0", "", "", ""])  # the input topic's row
    csv = write_ros_csv(tmp_path / "ros.csv", rows)
    m = load_mapping(synthetic_mapping(tmp_path), ["u.scale=10", "rows.resample_hz=1000", "u.to_torque=true"])
    assert m.u.scale == 10.0 and m.rows.resample_hz == 1000.0
    rig = load_rig("macstepien")
    rec = read_mapped_csv(csv, m, rig)
    assert np.allclose(np.diff(rec.t), 0.001) and len(rec) == 118
    a = rig.actuator
    v = 20.0  # 2 V × 10
    phi_dot = 0.01 / 0.003
    on = rec.t > 0.02
    assert np.allclose(rec.u[on][1:-1], a.Kt * (v - a.Ke * phi_dot) / a.R, rtol=1e-6)
    with pytest.raises(UserError, match="dc_motor"):
        read_mapped_csv(csv, m, load_rig("thesis"))


@pytest.mark.parametrize(("rows", "expected"), [
    ([["0", "", "1", "x", "0"], ["1", "", "2", "0", "0"]], r"line 2, column '/js/arm': 'x' is not a number"),
    ([["0", "", "", "", ""]], "fewer than two rows"),
])
def test_bad_csv_values(tmp_path: Path, rows: list[list[str]], expected: str) -> None:
    csv = write_ros_csv(tmp_path / "ros.csv", rows)
    with pytest.raises(UserError, match=expected):
        read_mapped_csv(csv, load_mapping(synthetic_mapping(tmp_path)))


def test_missing_column_names_the_column_and_the_fix(tmp_path: Path) -> None:
    csv = tmp_path / "other.csv"
    csv.write_text("time,angle\n0,1\n1,2\n")
    with pytest.raises(UserError) as err:
        read_recording(csv, "macstepien")
    msg = str(err.value)
    assert "'/joint_states/header/stamp'" in msg and "time, angle" in msg and "fix the mapping" in msg
    assert "\n" not in msg


@pytest.mark.parametrize(("override", "expected"), [
    ("u.scale", "FIELD.KEY=VALUE"),
    ("u.bogus=1", "mapping key 'u.bogus': unknown key"),
    ("theta.offset=half", "offset 'half'"),
    ("theta.wrap=sometimes", "mapping key 'theta.wrap'"),
])
def test_bad_mapping_overrides(override: str, expected: str) -> None:
    with pytest.raises(UserError, match=expected):
        load_mapping("macstepien", [override])


def test_unknown_mapping() -> None:
    with pytest.raises(UserError, match="neither a shipped mapping"):
        load_mapping("no-such-rig")
