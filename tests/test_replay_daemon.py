"""Replay of a real run: the daemon (`furuta-rt run --mock`: hil-mock on a pty) logs, replay re-runs the
same update over the log and gets the logged u and φ̂̇ back bit for bit."""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pytest
from test_reliability_harness import FURUTA_RT, LOCKSTEP, ROOT, traceback_free, write_test_rig

from furuta_rt.io.mcap_read import read_log
from furuta_rt.replay import replay_log

pytestmark = pytest.mark.hil


def test_replay_of_a_daemon_mock_run_is_exact(tmp_path: Path) -> None:
    log_path = tmp_path / "run.mcap"
    run = subprocess.run(
        [*FURUTA_RT, "run", "--mock", "--duration", "2", "--log", str(log_path), "--no-tui", "--comp", "lugre",
         "--config", str(write_test_rig(tmp_path)), "--mock-effect", "arm_coulomb.Fc=0.2", "--mock-seed", "5",
         LOCKSTEP],  # the device's time decides the tick count, not the machine's load
        capture_output=True, text=True, cwd=ROOT, timeout=240,
    )
    assert run.returncode == 0 and traceback_free(run.stderr), run.stderr
    log = read_log(log_path)
    assert not log.recovered and log.mode == "lugre" and log.n_ticks > 900
    result = replay_log(log)
    balancing = result.balancing
    assert balancing.sum() > 0.9 * log.n_ticks
    assert result.same_config and result.exact, result.verdict()
    assert np.array_equal(result.u[balancing], log.ticks["u"][balancing])
    assert result.n_phi_dot_mismatch == 0
    assert np.abs(result.u_comp[balancing]).max() > 0.0  # LuGre's bristle state was exercised
    other = replay_log(log, mode="none")
    assert other.n_mismatch > 0.9 * balancing.sum()
    cli = subprocess.run([*FURUTA_RT, "replay", str(log_path)], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert cli.returncode == 0 and "determinism check passed" in cli.stdout, cli.stdout + cli.stderr
