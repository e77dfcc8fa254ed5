"""Real-time setup of the control process: frozen GC, SCHED_FIFO, locked memory, idle CPUs that wake at once, CPU
affinity (with the kernel's tty work on the same CPU).

Each step is attempted and, when the system does not permit it, turned into a warning naming the
fix; none is ever a failure (the loop still runs, with more jitter).
"""

from __future__ import annotations

import atexit
import contextlib
import ctypes
import ctypes.util
import gc
import os

from furuta_rt.cpu_idle import hold_wakeup_latency
from furuta_rt.cpu_placement import MovedThreads, UnboundWork, confine_unbound_work, move_kernel_threads_off, pin_cpu

MCL_CURRENT = 1
MCL_FUTURE = 2


_HELD: list[int] = []  # the PM QoS request's descriptor: open for the life of the control process
_CONFINED: list[UnboundWork | MovedThreads] = []  # the kernel's unbound work on the loop's CPU, its housekeeping
# threads off it, until release_cpu_work()
_OTHER_CPUS: set[int] = set()  # the CPUs besides the one the loop is pinned to: where its helper processes run

CONTROL_THREAD_STACK = 1 << 20  # bytes: a helper thread of the control process (queue feeder, watcher) needs little


def lean_process() -> None:
    """Before numpy is imported into the real-time process: OpenBLAS with one thread. Its worker threads (one
    per core) each keep a 32 MB buffer that mlockall would lock, for linear algebra no tick does."""
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def freeze_gc() -> None:
    """Collect once, move every object to the permanent generation and stop the cyclic collector:
    no collection pause can hit a tick (the loop creates no reference cycles)."""
    gc.collect()
    gc.freeze()
    gc.disable()


def set_fifo(priority: int = 50) -> str | None:
    """SCHED_FIFO for the calling thread (children reset to normal scheduling). Warning or None."""
    if not hasattr(os, "SCHED_FIFO"):
        return "SCHED_FIFO is not available on this system: the loop runs at normal priority"
    try:
        policy = os.SCHED_FIFO | getattr(os, "SCHED_RESET_ON_FORK", 0)
        os.sched_setscheduler(0, policy, os.sched_param(priority))
    except (PermissionError, OSError) as err:
        return (f"SCHED_FIFO not permitted ({err.strerror}): the loop runs at normal priority. Fix: grant "
                "rtprio (e.g. '@realtime - rtprio 95' in /etc/security/limits.conf) or CAP_SYS_NICE")
    return None


def lock_memory() -> str | None:
    """mlockall(MCL_CURRENT | MCL_FUTURE): no page fault in a tick. Warning or None."""
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name, use_errno=True)
    except OSError:
        return "cannot load libc to lock memory: page faults may delay ticks"
    if libc.mlockall(MCL_CURRENT | MCL_FUTURE) != 0:
        err = ctypes.get_errno()
        return (f"mlockall failed ({os.strerror(err)}): page faults may delay ticks. Fix: raise the memlock "
                "limit (ulimit -l unlimited, or 'memlock' in /etc/security/limits.conf)")
    return None


def keep_off_loop_cpu(pid: int) -> None:
    """Move a helper process (logger, dashboard) off the CPU the loop is pinned to: there its work would compete with
    the kernel's tty work, which the loop's round trip waits for. Nothing when the loop is not pinned."""
    if _OTHER_CPUS:
        with contextlib.suppress(OSError):  # the process has just ended: nothing to move
            os.sched_setaffinity(pid, _OTHER_CPUS)


def setup_realtime(enable: bool = True, priority: int = 50, cpu: int | None = None) -> tuple[list[str], list[str]]:
    """Apply the real-time settings; returns (what was applied, warnings). ``enable=False``: GC only."""
    freeze_gc()
    applied = ["gc frozen and disabled"]
    if not enable:
        return applied, []
    warnings: list[str] = []
    # memory first: mlockall faults in every page of the process (hundreds of ms of kernel time), which
    # must not run at real-time priority where it would hold a CPU against other real-time tasks
    mem_warning = lock_memory()
    if mem_warning:
        warnings.append(mem_warning)
    else:
        applied.append("memory locked")
    held, idle_warning = hold_wakeup_latency(0)  # held until the process exits
    if idle_warning:
        warnings.append(idle_warning)
    elif held is not None:
        _HELD.append(held)
        applied.append("idle CPUs wake at once (PM QoS 0 µs)")
    fifo_warning = set_fifo(priority)
    if fifo_warning:
        warnings.append(fifo_warning)
    else:
        applied.append(f"SCHED_FIFO priority {priority}")
        if cpu is not None:  # opt-in: on a shared machine a pinned task cannot flee a busy CPU
            allowed = os.sched_getaffinity(0)
            pinned, w = pin_cpu(cpu)
            if w:
                warnings.append(w)
            if pinned is not None:
                _OTHER_CPUS.clear()
                _OTHER_CPUS.update(allowed - {pinned})
                applied.append(f"pinned to CPU {pinned}")
                confined, w = confine_unbound_work(pinned)
                if w:
                    warnings.append(w)
                if confined is not None:
                    _CONFINED.append(confined)
                    applied.append(f"the kernel's tty work on CPU {pinned} too (until the run ends)")
                moved, w = move_kernel_threads_off(pinned)
                if w:
                    warnings.append(w)
                if moved is not None:
                    _CONFINED.append(moved)
                    applied.append(f"{len(moved.original)} kernel housekeeping threads off CPU {pinned} (until the run "
                                   "ends)")
                if _CONFINED:
                    atexit.register(release_cpu_work)
    return applied, warnings


def release_cpu_work() -> list[str]:
    """Put the kernel's unbound work and housekeeping threads back where they were before
    ``setup_realtime(cpu=...)``; warnings, if any."""
    warnings = []
    while _CONFINED:
        w = _CONFINED.pop().restore()
        if w:
            warnings.append(w)
    return warnings
