"""Replay: the logged u comes back bit for bit with the logged config, in every compensation mode; another
mode or other gains change it; the replay rule (reset, hold outside balancing) is what makes it exact."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from furuta_rt.cli import main
from furuta_rt.config import RigConfig, load_rig
from furuta_rt.errors import UserError
from furuta_rt.io.mcap_read import read_log
from furuta_rt.model.effects import effects_from_assignments
from furuta_rt.replay import replay_log
from furuta_rt.replay.simulate import simulate_log

MODES = ("none", "coulomb", "stiction", "lugre")


@pytest.fixture(scope="module")
def rig() -> RigConfig:
    return load_rig("thesis")


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory, rig: RigConfig) -> dict[str, Path]:
    """2.5 s simulated daemon logs (with arm Coulomb friction, idle start, a re-arm) in every mode."""
    d = tmp_path_factory.mktemp("replay")
    effects = effects_from_assignments(["arm_coulomb.Fc=0.2"])
    return {
        mode: simulate_log(d / f"{mode}.mcap", rig, 2.5, mode=mode, effects=effects, substep_hz=2000, rearm=(1.5,), seed=3)
        for mode in MODES
    }


@pytest.mark.parametrize("mode", MODES)
def test_replay_reproduces_logged_u_exactly(logs: dict[str, Path], mode: str) -> None:
    log = read_log(logs[mode])
    assert log.mode == mode and log.warnings == []
    states = set(log.ticks["state"].tolist())
    assert states == {"idle", "balancing"}
    assert int(log.ticks["reset"].sum()) == 2  # arming and the re-arm
    result = replay_log(log)
    assert result.same_config and not result.converted
    n_bal = int(result.balancing.sum())
    assert n_bal == 1200  # 2.5 s at 500 Hz minus 0.1 s idle
    assert result.exact and result.n_mismatch == 0
    assert np.array_equal(result.u, log.ticks["u"])  # == on floats, idle ticks included (both 0)
    assert result.n_phi_dot_mismatch == 0
    assert np.array_equal(result.u_comp, log.ticks["u_comp"])
    assert "determinism check passed" in result.verdict()
    if mode != "none":
        assert np.abs(result.u_comp[result.balancing]).max() > 0.05  # the compensation did act


def test_another_mode_changes_u(logs: dict[str, Path]) -> None:
    log = read_log(logs["none"])
    result = replay_log(log, mode="coulomb")
    assert not result.same_config
    bal = result.balancing
    assert result.n_mismatch > 0.9 * bal.sum()
    # On the same data the linear part is the same up to the observer (which sees u − F̂, the same torque):
    # the difference is the compensation, bounded by the configured Fc = 0.3 N m of the thesis rig.
    du = result.u[bal] - log.ticks["u"][bal]
    assert np.allclose(du, result.u_comp[bal], atol=1e-9)
    assert 0.1 < np.abs(du).max() <= 0.3 + 1e-12
    assert "replayed with mode coulomb" in result.verdict()


def test_other_gains_change_u(logs: dict[str, Path]) -> None:
    log = read_log(logs["none"])
    gains = [2.0 * g for g in log.gains]  # type: ignore[union-attr]
    result = replay_log(log, gains=gains)
    bal = result.balancing
    assert not result.same_config and result.n_mismatch > 0.9 * bal.sum()
    # At a reset the observer starts from the same state whatever the gains, so u = L·x doubles exactly;
    # afterwards the observer is driven by the (different) commanded torque and the runs part.
    resets = np.flatnonzero(log.ticks["reset"])
    assert not result.saturated[resets].any()
    assert np.allclose(result.u[resets], 2.0 * log.ticks["u"][resets], rtol=1e-12, atol=0.0)
    assert not np.allclose(result.phi_dot_hat[bal], log.ticks["phi_dot_hat"][bal])


def test_the_replay_rule_reset_is_what_makes_it_exact(logs: dict[str, Path]) -> None:
    log = read_log(logs["coulomb"])
    rearm = int(np.flatnonzero(log.ticks["reset"])[1])
    log.ticks["reset"][rearm] = False  # forget the re-arm: the observer and the pending command drift apart
    result = replay_log(log)
    mismatched = np.flatnonzero(result.u != log.ticks["u"])
    assert len(mismatched) > 0 and mismatched[0] == rearm


def test_replay_needs_ticks_and_a_rig(tmp_path: Path, rig: RigConfig, logs: dict[str, Path]) -> None:
    data = logs["none"].read_bytes()
    cut = tmp_path / "early.mcap"
    cut.write_bytes(data[:2000])  # metadata only, no complete chunk
    log = read_log(cut)
    assert log.n_ticks == 0 and log.recovered
    with pytest.raises(UserError, match=r"no complete ticks in this log \(cut before its first chunk"):
        replay_log(log)


def test_replay_cli_reports_determinism_and_writes_csv_and_plot(
    tmp_path: Path, logs: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    csv_out, png = tmp_path / "r.csv", tmp_path / "r.png"
    assert main(["replay", str(logs["lugre"]), "--csv", str(csv_out), "--plot", str(png)]) == 0
    out = capsys.readouterr().out
    assert "determinism check passed" in out
    assert "std" in out and "× real time" in out
    assert png.stat().st_size > 10_000
    header = csv_out.read_text().splitlines()[0].split(",")
    assert header[:5] == ["t", "theta", "theta_dot", "phi", "u"] and "u_logged" in header


def test_replay_cli_other_comp_and_json(logs: dict[str, Path], capsys: pytest.CaptureFixture[str]) -> None:
    import json

    assert main(["replay", str(logs["none"]), "--comp", "stiction", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["mode"] == "stiction" and not report["same_config"] and report["mismatches"] > 0
    assert set(report["stats"]) >= {"theta", "phi", "u", "limit_cycle_phi", "limit_cycle_theta"}


def test_replay_cli_truncated_log_warns_and_replays(
    tmp_path: Path, logs: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    data = logs["stiction"].read_bytes()
    cut = tmp_path / "killed.mcap"
    cut.write_bytes(data[: int(len(data) * 0.6)])
    assert main(["replay", str(cut)]) == 0
    captured = capsys.readouterr()
    assert "determinism check passed" in captured.out
    assert f"run `furuta-rt repair {cut}` to rewrite it with a summary" in captured.err
    assert "Traceback" not in captured.err


@pytest.mark.parametrize("content", [b"", b"not an mcap file\n", bytes(range(256)) * 4])
def test_replay_cli_not_mcap_is_a_one_line_error(tmp_path: Path, content: bytes, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(content)
    assert main(["replay", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(bad) in err and "furuta-rt convert" in err


def test_replay_cli_missing_file_and_bad_gains(tmp_path: Path, logs: dict[str, Path], capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["replay", str(tmp_path / "nope.mcap")]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert main(["replay", str(logs["none"]), "--gains", "1,2,3"]) == 2
    assert "exactly four gains" in capsys.readouterr().err
