"""diagnose's input sanity, through the real CLI: a non-MCAP file named .mcap, a torn MCAP, time in ms or µs."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
from test_reliability_harness import FURUTA_RT

from furuta_rt.config import load_rig
from furuta_rt.diagnose.sanity import time_in_seconds
from furuta_rt.io.csv import write_csv
from furuta_rt.io.mcap_log import write_recording_mcap
from furuta_rt.recording import Recording


def _cli(cwd: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*FURUTA_RT, *args], cwd=cwd, capture_output=True, text=True, timeout=300)


def _rec(seconds: float = 6.0) -> Recording:
    t = np.arange(round(seconds * 500)) / 500.0
    return Recording(t=t, theta=0.01 * np.sin(3 * t), phi=0.1 * np.sin(t), u=0.1 * np.cos(3 * t),
                     theta_dot=0.03 * np.cos(3 * t))


def test_a_csv_named_mcap_is_refused_as_not_mcap(tmp_path: Path) -> None:
    write_csv(_rec(), tmp_path / "run.mcap")
    proc = _cli(tmp_path, "diagnose", "run.mcap", "--no-closed-loop")
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    assert len(lines) == 1 and "not an MCAP file" in lines[0] and "run.mcap" in lines[0], proc.stderr


def test_a_torn_mcap_is_warned_about_and_read_to_its_end(tmp_path: Path) -> None:
    good = tmp_path / "good.mcap"
    write_recording_mcap(_rec(8.0), good, load_rig("thesis"))
    torn = tmp_path / "torn.mcap"
    torn.write_bytes(good.read_bytes()[:-1000])  # every chunk kept, the summary cut
    proc = _cli(tmp_path, "diagnose", "torn.mcap", "--no-closed-loop", "--json", "d.json")
    assert proc.returncode == 0, proc.stderr
    assert "warning" in proc.stderr and "not closed properly" in proc.stderr and "recovered" in proc.stderr
    assert torn.read_bytes() == good.read_bytes()[:-1000]  # the user's file untouched


def test_time_in_milliseconds_and_microseconds_is_converted_with_a_note(tmp_path: Path) -> None:
    rec = _rec()
    for scale, unit in ((1e3, "ms"), (1e6, "µs")):
        fixed, note = time_in_seconds(Recording(t=rec.t * scale, theta=rec.theta, phi=rec.phi, u=rec.u))
        assert note is not None and unit in note and "500 Hz" in note
        assert np.allclose(fixed.t, rec.t)
    assert time_in_seconds(rec) == (rec, None)
    slow = Recording(t=rec.t[::25], theta=rec.theta[::25], phi=rec.phi[::25], u=rec.u[::25])  # 20 Hz in s
    assert time_in_seconds(slow)[1] is None
    write_csv(Recording(t=rec.t * 1e3, theta=rec.theta, phi=rec.phi, u=rec.u, theta_dot=rec.theta_dot),
              tmp_path / "ms.csv")
    proc = _cli(tmp_path, "diagnose", "ms.csv", "--no-closed-loop", "--json", "d.json")
    assert proc.returncode == 0, proc.stderr
    assert "read as ms" in proc.stderr
    d = json.loads((tmp_path / "d.json").read_text())
    assert any("read as ms" in n for n in d["notes"])
