"""The PM QoS CPU latency request (furuta_rt.cpu_idle): held while its descriptor is open, read back from the
kernel; every way it cannot be had is a one-line warning naming the file and the fix, never an exception."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from furuta_rt.cpu_idle import CPU_LATENCY_DEVICE, current_wakeup_latency_us, hold_wakeup_latency


def test_the_kernel_applies_the_request_while_it_is_held() -> None:
    """Where this user may write the device (root), the kernel's bound is 0 while held; elsewhere the warning."""
    fd, warning = hold_wakeup_latency(0)
    if not os.access(CPU_LATENCY_DEVICE, os.W_OK):
        assert fd is None and warning is not None and CPU_LATENCY_DEVICE in warning
        return
    try:
        assert warning is None and fd is not None
        assert current_wakeup_latency_us() == 0  # the tightest request any process holds: this one
        assert os.readlink(f"/proc/self/fd/{fd}") == CPU_LATENCY_DEVICE
    finally:
        if fd is not None:
            os.close(fd)


def test_without_the_device_a_warning_names_it(tmp_path: Path) -> None:
    missing = str(tmp_path / "cpu_dma_latency")
    fd, warning = hold_wakeup_latency(0, device=missing)
    assert fd is None and warning is not None and missing in warning and "PM QoS" in warning
    assert current_wakeup_latency_us(missing) is None


def test_a_device_that_refuses_the_request_is_closed_and_named() -> None:
    before = len(os.listdir("/proc/self/fd"))
    fd, warning = hold_wakeup_latency(0, device="/dev/full")  # opens, and every write fails (ENOSPC)
    assert fd is None and warning is not None and "/dev/full refused a 0 µs request" in warning
    assert len(os.listdir("/proc/self/fd")) == before  # nothing left open


def test_no_permission_names_the_fix(monkeypatch: pytest.MonkeyPatch) -> None:
    def denied(*_: object) -> int:
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(os, "open", denied)
    fd, warning = hold_wakeup_latency(0)
    assert fd is None and warning is not None
    assert "not writable" in warning and "udev rule" in warning and "\n" not in warning
