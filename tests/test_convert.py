"""`furuta-rt convert`: CSV ⇄ MCAP round trips, other rigs' CSVs, and one-line errors (exit 2)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from furuta_rt.cli import main
from furuta_rt.config import load_rig
from furuta_rt.io.csv import read_csv, write_csv
from furuta_rt.io.mcap_log import write_recording_mcap
from furuta_rt.io.mcap_read import read_log
from furuta_rt.io.recordings import read_recording
from furuta_rt.recording import Recording
from furuta_rt.replay import replay_log
from furuta_rt.sim.closed_loop import run_closed_loop

REALDATA = Path(__file__).resolve().parents[2] / "shared" / "realdata" / "macstepien-furuta"


def recording(theta_dot: bool) -> Recording:
    t = np.arange(200) * 0.002
    rng = np.random.default_rng(1)
    return Recording(
        t=t, theta=0.05 * np.sin(3 * t) + 1e-4 * rng.standard_normal(200), phi=0.3 * np.cos(t),
        u=0.2 * np.sin(5 * t), theta_dot=0.15 * np.cos(3 * t) if theta_dot else None,
    )


@pytest.mark.parametrize("theta_dot", [True, False])
def test_csv_mcap_csv_round_trip_is_exact(tmp_path: Path, theta_dot: bool) -> None:
    src = tmp_path / "in.csv"
    write_csv(recording(theta_dot), src)
    assert main(["convert", str(src), "-o", str(tmp_path / "log.mcap")]) == 0
    assert main(["convert", str(tmp_path / "log.mcap"), "-o", str(tmp_path / "out.csv")]) == 0
    assert (tmp_path / "out.csv").read_text() == src.read_text()
    a, b = read_csv(src), read_csv(tmp_path / "out.csv")
    assert np.array_equal(a.u, b.u) and (b.theta_dot is None) == (not theta_dot)
    log = read_log(tmp_path / "log.mcap")
    assert log.converted and log.rig is not None and log.rig.name == "thesis"
    assert ("theta_dot" in log.run["derived"]) == (not theta_dot)  # θ̇ = dθ/dt in the log's ticks, not in the CSV


def test_a_simulated_recording_converted_replays_to_the_same_u(tmp_path: Path) -> None:
    """run_closed_loop and replay run the same update: its recording, as a log, replays exactly."""
    rig = load_rig("thesis")
    rec = run_closed_loop(rig, 1.0, mode="coulomb", substep_hz=2000)
    path = write_recording_mcap(rec, tmp_path / "sim.mcap", rig, mode="coulomb")
    result = replay_log(read_log(path))
    assert result.converted and result.n_mismatch == 0 and np.array_equal(result.u, rec.u)
    assert "not furuta-rt's" in result.verdict()


def test_macstepien_convert_replay_and_plot(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "step.mcap"
    png = tmp_path / "step.png"
    src = REALDATA / "hardware_step_response_2V.csv"
    assert main(["convert", str(src), "--mapping", "macstepien", "-o", str(out), "--plot", str(png)]) == 0
    assert "rig macstepien" in capsys.readouterr().out and png.stat().st_size > 10_000
    log = read_log(out)
    assert log.rig is not None and log.rig.actuator.kind == "dc_motor" and log.n_ticks == 3424
    assert main(["replay", str(out), "--plot", str(tmp_path / "replay.png")]) == 0
    assert "recorded input" in capsys.readouterr().out
    rec = read_recording(out)
    direct = read_recording(src, "macstepien")
    assert np.array_equal(rec.theta, direct.theta) and np.array_equal(rec.u, direct.u) and rec.theta_dot is None


def test_map_overrides_on_the_command_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    src = REALDATA / "hardware_step_response_01.csv"
    out = tmp_path / "step.csv"
    assert main(["convert", str(src), "--mapping", "macstepien", "--map", "u.scale=10", "-o", str(out)]) == 0
    assert "moved back" in capsys.readouterr().out
    assert set(np.unique(read_csv(out).u).tolist()) == {0.0, 1.0}


@pytest.mark.parametrize(("content", "expected"), [
    ("t,theta,u\n0,0,0\n1,0,0\n", "missing column(s) phi"),
    ("t,theta,phi,u\n0,0,0,0\n1,0,zero,0\n", "line 3, column 'phi': 'zero' is not a number"),
    ("t,theta,phi,u\n0,0,0,0\n0,0,0,0\n", "not strictly increasing"),
    ("", "empty file"),
])
def test_bad_csv_is_a_one_line_error(tmp_path: Path, content: str, expected: str, capsys: pytest.CaptureFixture[str]) -> None:
    src = tmp_path / "bad.csv"
    src.write_text(content)
    assert main(["convert", str(src), "-o", str(tmp_path / "out.mcap")]) == 2
    err = capsys.readouterr().err.strip()
    assert expected in err and len(err.splitlines()) == 1 and "Traceback" not in err
    assert not (tmp_path / "out.mcap").exists()


@pytest.mark.parametrize(("args", "expected"), [
    (["--map", "u.scale=2"], "--map needs --mapping"),
    (["--mapping", "nonesuch"], "neither a shipped mapping"),
    (["--config", "nonesuch.toml"], "does not exist"),
])
def test_bad_options(tmp_path: Path, args: list[str], expected: str, capsys: pytest.CaptureFixture[str]) -> None:
    src = tmp_path / "in.csv"
    write_csv(recording(True), src)
    assert main(["convert", str(src), "-o", str(tmp_path / "out.mcap"), *args]) == 2
    assert expected in capsys.readouterr().err


def test_output_format_and_mcap_to_mcap(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    src = tmp_path / "in.csv"
    write_csv(recording(True), src)
    assert main(["convert", str(src), "-o", str(tmp_path / "out.parquet")]) == 2
    assert "use .csv or .mcap" in capsys.readouterr().err
    assert main(["convert", str(src), "-o", str(tmp_path / "log.mcap")]) == 0
    assert main(["convert", str(tmp_path / "log.mcap"), "-o", str(tmp_path / "log2.mcap")]) == 2
    assert "furuta-rt repair" in capsys.readouterr().err
