"""Keep idle CPUs awake enough for a 1 kHz loop: the kernel's PM QoS CPU latency request.

A SAMPLE wakes a sleeping process on an idle CPU. An idle CPU in a deep C-state, or a virtual CPU its hypervisor has
halted, takes tens of µs to milliseconds to come back, on every period. Writing a latency bound to
``/dev/cpu_dma_latency`` and keeping the file open asks cpuidle for idle states that wake within it (0 µs: idle
CPUs poll); closing it, or the process ending, withdraws the request. cyclictest does the same by default, and
real-time figures without it measure the idle states, not the loop. The cost is power: idle CPUs stay busy-idle
while the request is held.
"""

from __future__ import annotations

import os
import struct

CPU_LATENCY_DEVICE = "/dev/cpu_dma_latency"


def hold_wakeup_latency(max_us: int = 0, device: str = CPU_LATENCY_DEVICE) -> tuple[int | None, str | None]:
    """Request that idle CPUs wake within ``max_us``; returns (the file descriptor that holds the request, or None;
    a warning naming the fix, or None). The request lasts until the descriptor is closed or the process exits."""
    try:
        fd = os.open(device, os.O_WRONLY)
    except FileNotFoundError:
        return None, f"no {device} (a kernel without PM QoS): idle CPUs may wake late for each SAMPLE"
    except PermissionError:
        return None, (f"{device} is not writable: idle CPUs may wake late for each SAMPLE. Fix: run as root, or "
                      f"let the real-time group write it (a udev rule: KERNEL==\"cpu_dma_latency\", GROUP=\"realtime\", "
                      f"MODE=\"0660\")")
    except OSError as err:
        return None, f"cannot open {device} ({err.strerror}): idle CPUs may wake late for each SAMPLE"
    try:
        os.write(fd, struct.pack("i", max_us))
    except OSError as err:
        os.close(fd)
        return None, f"{device} refused a {max_us} µs request ({err.strerror}): idle CPUs may wake late for each SAMPLE"
    return fd, None


def current_wakeup_latency_us(device: str = CPU_LATENCY_DEVICE) -> int | None:
    """The bound the kernel applies now (the tightest request held by any process), or None if unreadable."""
    try:
        with open(device, "rb") as f:
            data = f.read(4)
    except OSError:
        return None
    return struct.unpack("i", data)[0] if len(data) == 4 else None
