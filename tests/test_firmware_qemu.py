"""The cross-compiled firmware core under qemu-system-arm, talked to by the real daemon over qemu's pty.

The image (firmware/stm32f4/qemu_board.c) is the core and codec built for the Cortex-M4 exactly as for the board,
on qemu's netduinoplus2 (an STM32F405: the F401's USART2, TIM5 and NVIC), with the thesis rig simulated in the
image from its sampled linear model (hil_mock/qemu.py, generated from furuta_rt's model). ``furuta-rt run --port
/dev/pts/N`` handshakes with it, arms and balances.

qemu is not a real-time device: on a loaded 2-core machine its SysTick interrupts come late and are not
made up, and the host shares the machine (measured: a host loop at 377 Hz tripped the pendulum at θ > 0.5 rad
when the image ran free). The image therefore runs in lockstep with the host (qemu_board.c: a tick waits, up to
100 periods, for the COMMAND answering the last SAMPLE), so the closed loop is the same at any load. The host's
limits are those of ``--mock`` (500 ms link timeout and device watchdog) with the overrun trip off (the host's
wall-clock periods are not the device's); what is asserted is the device's identity in the handshake, no CRC
error, and the pendulum balanced to the end with |θ| small (from the run's log).

Needs arm-none-eabi-gcc, picolibc and qemu-system-arm, which scripts/build_firmware (run first by scripts/test)
installs when it may; without them this test is skipped with that reason, as the cross build is.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from test_reliability_harness import DaemonProcess, read_summary, traceback_free

from furuta_rt.config import load_rig
from furuta_rt.io.mcap_read import read_log
from hil_mock.qemu import build_image, start_qemu, tools_missing

pytestmark = pytest.mark.hil


def test_furuta_rt_run_balances_the_cross_compiled_core_under_qemu(tmp_path: Path) -> None:
    missing = tools_missing()
    if missing:
        pytest.skip(f"{', '.join(missing)} not installed; scripts/build_firmware installs them (as root with apt-get)")
    proc, pty = start_qemu(build_image(load_rig(None)))
    try:
        d = DaemonProcess(["--port", pty, "--duration", "3", "--no-tui", "--no-rt", "--watchdog-ms", "500",
                           "--link-timeout-ms", "500", "--max-overruns", "1000000", "--log", str(tmp_path / "run.mcap"),
                           "--summary-json", str(tmp_path / "summary.json")])
        rc = d.wait(timeout=60)
    finally:
        proc.kill()
        proc.wait(10)
    out = d.stdout + "\n".join(d.lines)
    assert traceback_free(out), out
    assert rc == 0, f"exit {rc}\n{out}"
    assert f"device 0x51454d55 firmware 0.3.0 at {pty}, 500 Hz" in out  # the image's HELLO_ACK
    s = read_summary(tmp_path)
    assert s["end"] == "duration" and s["ticks"] == 3 * 500 and s["balanced_s"] > 2.9
    assert s["crc_errors"] == 0
    log = read_log(tmp_path / "run.mcap")
    assert log.n_ticks == 3 * 500 and np.abs(log.ticks["theta"][250:]).max() < 0.05  # after its first half second
