"""The exit code says the run's outcome first (tests/test_signals.py has the signals): a trip stays 1 when
an output after the run fails (an unwritable --summary-json, a stdout nobody reads), and that failure is
one more line, never a traceback. A broken pipe is not called a path or permission problem."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

from test_reliability_harness import (
    FURUTA_RT,
    ROOT,
    MockProcess,
    start_daemon,
    traceback_free,
    write_test_rig,
)


def test_a_trip_stays_exit_1_when_the_summary_json_cannot_be_written(tmp_path: Path) -> None:
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    mock = MockProcess(tmp_path, [])
    daemon = start_daemon(tmp_path, mock.port, duration=60.0, extra=["--summary-json", str(out_dir / "s.json")])
    try:
        daemon.wait_for_line("→ balancing")
        shutil.rmtree(out_dir)  # the directory of --summary-json is gone when the run ends
        mock.disconnect()  # the device vanishes: trip link_loss
        rc = daemon.wait()
    finally:
        mock.stop()
    assert traceback_free(daemon.stderr + daemon.stdout), daemon.stderr
    assert rc == 1, daemon.stderr
    lines = [line for line in daemon.stderr.splitlines() if "--summary-json" in line]
    assert len(lines) == 1 and "not written" in lines[0], daemon.stderr
    assert "→ tripped" in daemon.stderr, daemon.stderr


def test_a_trip_stays_exit_1_when_stdout_is_a_broken_pipe(tmp_path: Path) -> None:
    mock = MockProcess(tmp_path, [])
    r, w = os.pipe()
    os.close(r)  # nobody reads the summary (`furuta-rt run ... | head -0`, a closed terminal)
    args = ["run", "--port", mock.port, "--config", str(write_test_rig(tmp_path)), "--no-tui", "--duration", "60",
            "--watchdog-ms", "500"]
    proc = subprocess.Popen([*FURUTA_RT, *args], stdout=w, stderr=subprocess.PIPE, text=True, cwd=ROOT,
                            start_new_session=True)
    os.close(w)
    lines: list[str] = []
    try:
        assert proc.stderr is not None
        for line in proc.stderr:
            lines.append(line)
            if "→ balancing" in line:
                mock.disconnect()
                break
        rest = proc.communicate(timeout=120)[1]
    finally:
        if proc.poll() is None:
            proc.kill()
        mock.stop()
    err = "".join(lines) + rest
    assert traceback_free(err), err
    assert proc.returncode == 1, err
    assert "check the path" not in err, err
    assert "could not be printed" in err, err
