"""What a device answers in its HELLO_ACK, through the real daemon (a subprocess) against a scripted device
on a pty (tests/test_run_loop.py's ScriptedDaq): a field no rig can use is one line and exit 2, after STOP
went out; an unknown actuator kind is not called a DC motor; each warning about the device prints once."""

from __future__ import annotations

import subprocess
from typing import Any

import pytest
from test_reliability_harness import FURUTA_RT, ROOT, traceback_free
from test_run_loop import ScriptedDaq

import firmware_protocol as fp


def _run(ack: dict[str, Any]) -> tuple[subprocess.CompletedProcess, list[Any]]:
    daq = ScriptedDaq(ack)
    try:
        proc = subprocess.run([*FURUTA_RT, "run", "--port", daq.port, "--no-tui", "--duration", "1"],
                              capture_output=True, text=True, cwd=ROOT, timeout=120)
    finally:
        daq.close()
    return proc, daq.received


@pytest.mark.parametrize(("ack", "needle"), [
    ({"phi_counts_per_rev": 0}, "phi_counts_per_rev = 0"),
    ({"theta_rad_per_count": -1e-4}, "theta_rad_per_count = -0.0001"),
    ({"theta_dot_rad_s_per_count": 0.0}, "theta_dot_rad_s_per_count = 0"),
    ({"actuator_kind": 7}, "actuator_kind = 7"),
], ids=["phi_counts_0", "negative_adc_scale", "zero_rate_scale", "actuator_kind_7"])
def test_an_unusable_hello_ack_is_one_line_exit_2_after_stop(ack: dict[str, Any], needle: str) -> None:
    proc, received = _run(ack)
    err = proc.stderr.strip()
    assert traceback_free(err + proc.stdout), err
    assert proc.returncode == 2, err
    assert len(err.splitlines()) == 1 and needle in err and "HELLO_ACK" in err, err
    assert "dc_motor" not in err
    assert any(isinstance(m, fp.Stop) for m in received), "STOP went out before the message"


def test_each_device_warning_prints_once() -> None:
    """A device whose calibration differs from the config (4096 counts/rev, other ADC scales) and then never
    streams: the warnings are said once each, then the link-loss trip."""
    proc, _ = _run({})
    warnings = [line for line in proc.stderr.splitlines() if "warning:" in line and "device" in line]
    assert warnings, proc.stderr
    assert len(warnings) == len(set(warnings)), proc.stderr
