"""Where the real-time threads run: one CPU for the loop, the device it talks to and the kernel's tty work.

``pin_cpu`` pins the calling thread (the control loop; hil-mock's device thread). ``confine_unbound_work`` moves the
kernel's unbound work to that CPU; ``move_kernel_threads_off`` moves the kernel's housekeeping threads off it.

Bytes written to a pseudo-terminal (and bytes a USB-serial adapter receives) reach the reader through a kernel work
item (``flush_to_ldisc``) on an *unbound* workqueue, run by a normal-priority kworker on whichever CPU the scheduler
picks, usually an idle one. So each period of a SAMPLE → COMMAND round trip wakes CPUs besides the loop's: a virtual
CPU its hypervisor is not running at that moment wakes milliseconds later, and the period is missed. With the loop
(and, with ``--mock``, the device) pinned to one CPU and the unbound work confined to it too, a round trip needs no
other CPU: what remains is that one CPU's own stalls, the floor a lone SCHED_FIFO thread measures.

The flush work runs at normal priority, so on that CPU it waits behind any normal-priority task there. Among those
are the kernel's own housekeeping threads (memory reclaim and monitoring such as kswapd, kcompactd, kdamond; RCU;
kthreadd): a kernel trace of 1 kHz runs found the tty work waiting behind kdamond for more than a period. Those that
may run anywhere are moved to the other CPUs for the run, as real-time setups isolate a CPU (tuna --isolate, or
isolcpus at boot); threads bound to one CPU and the kernel's own workers stay.

Both changes are machine-wide. So they are made only on request (``furuta-rt run --cpu N``), undone when the run
ends, and the originals are kept in a state file first, so that a run killed before it could undo them (SIGKILL) is
undone by the next run that makes them.
"""

from __future__ import annotations

import contextlib
import os
from dataclasses import dataclass
from pathlib import Path

from furuta_rt.errors import UserError

WORKQUEUE_CPUMASK = Path("/sys/devices/virtual/workqueue/cpumask")
STATE_FILE = Path("/run/furuta-rt/unbound-work-cpumask")
KERNEL_THREADS_STATE_FILE = Path("/run/furuta-rt/kernel-threads")
PF_KTHREAD = 0x00200000  # /proc/PID/stat flags: a kernel thread
PF_NO_SETAFFINITY = 0x04000000  # … whose CPUs the kernel manages (per-CPU threads, workqueue workers)


def pin_cpu(cpu: int | None = None) -> tuple[int | None, str | None]:
    """Pin the calling thread to ``cpu`` (None: the last allowed CPU when there are ≥ 2)."""
    try:
        allowed = sorted(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return None, "CPU affinity not available on this system"
    if cpu is None:
        if len(allowed) < 2:
            return None, None
        cpu = allowed[-1]
    if cpu not in allowed:
        return None, f"CPU {cpu} is not available to this process (allowed: {allowed}); not pinned"
    try:
        os.sched_setaffinity(0, {cpu})
    except OSError as err:
        return None, f"cannot pin to CPU {cpu} ({err.strerror}); not pinned"
    return cpu, None


def check_cpu_option(cpu: int) -> None:
    """``--cpu N`` names a CPU this process may run on; UserError otherwise (a typo would run the thread unpinned)."""
    allowed = sorted(os.sched_getaffinity(0))
    if cpu not in allowed:
        raise UserError(f"--cpu {cpu}: not a CPU this process may run on (allowed: "
                        f"{', '.join(map(str, allowed))}); give one of them, or leave --cpu out")


def cpu_mask(cpus: set[int]) -> str:
    """The kernel's hexadecimal CPU mask of ``cpus`` (CPU 0 is bit 0)."""
    return format(sum(1 << c for c in cpus), "x")


def mask_cpus(mask: str) -> set[int]:
    """The CPUs of a kernel mask as the cpumask file shows it (hex, possibly comma-grouped)."""
    bits = int(mask.strip().replace(",", ""), 16)
    return {c for c in range(bits.bit_length()) if bits >> c & 1}


@dataclass
class UnboundWork:
    """A confinement held by this process; ``restore()`` puts the original mask back (once)."""

    original: str
    mask_file: Path
    state_file: Path
    restored: bool = False

    def restore(self) -> str | None:
        """Put the mask back; a warning naming what is left if that fails, else None."""
        if self.restored:
            return None
        self.restored = True
        try:
            self.mask_file.write_text(self.original)
        except OSError as err:
            return (f"cannot put the kernel's unbound work back on CPUs {self.original} ({err.strerror}): write it to "
                    f"{self.mask_file}")
        with contextlib.suppress(OSError):
            self.state_file.unlink()
        return None


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _undo_stale(mask_file: Path, state_file: Path) -> tuple[int | None, str | None]:
    """A state file left by another run: (its pid if that run is alive, else None after putting its original back;
    a warning if the original could not be restored)."""
    try:
        pid_text, original = state_file.read_text().split()
        pid = int(pid_text)
    except (OSError, ValueError):
        return None, None
    if pid != os.getpid() and _alive(pid):
        return pid, None
    try:
        mask_file.write_text(original)
    except OSError as err:
        return None, f"cannot restore the unbound work mask {original} a killed run left ({err.strerror})"
    with contextlib.suppress(OSError):
        state_file.unlink()
    return None, None


def confine_unbound_work(cpu: int, mask_file: Path = WORKQUEUE_CPUMASK,
                         state_file: Path = STATE_FILE) -> tuple[UnboundWork | None, str | None]:
    """Confine the kernel's unbound work (the tty's flush work among it) to ``cpu``; returns (the held confinement,
    or None; a warning naming why not, or None)."""
    if not mask_file.exists():
        return None, f"no {mask_file} (a kernel without it): the tty's kernel work may run on another CPU"
    holder, warning = _undo_stale(mask_file, state_file)
    if holder is not None:
        return None, (f"another furuta-rt run (pid {holder}) holds the kernel's unbound work on its CPU; this run "
                      "leaves the mask as it is")
    try:
        original = mask_file.read_text().strip()
        if cpu not in mask_cpus(original):
            return None, (f"CPU {cpu} is not among the CPUs of the kernel's unbound work ({original}); the tty's "
                          "kernel work stays where it is")
        state_file.parent.mkdir(parents=True, exist_ok=True)
        state_file.write_text(f"{os.getpid()} {original}\n")
        mask_file.write_text(cpu_mask({cpu}))
    except PermissionError:
        with contextlib.suppress(OSError):
            state_file.unlink()
        return None, (f"{mask_file} is not writable: the tty's kernel work may run on another CPU, which a round trip "
                      "then waits for. Fix: run as root")
    except OSError as err:
        with contextlib.suppress(OSError):
            state_file.unlink()
        return None, f"cannot confine the kernel's unbound work to CPU {cpu} ({err.strerror})"
    return UnboundWork(original, mask_file, state_file), warning


@dataclass
class MovedThreads:
    """Kernel threads moved off a CPU by this process: pid → (name, the CPUs it had); ``restore()`` gives each its
    CPUs back (once), if it is still the same thread."""

    original: dict[int, tuple[str, set[int]]]
    state_file: Path
    proc: Path = Path("/proc")
    restored: bool = False

    def restore(self) -> str | None:
        """Give the threads their CPUs back; a warning naming those it could not, else None."""
        if self.restored:
            return None
        self.restored = True
        failed = _give_back(self.original, self.proc)
        with contextlib.suppress(OSError):
            self.state_file.unlink()
        if failed:
            return f"cannot give kernel threads their CPUs back: {', '.join(failed)}"
        return None


def _comm(pid: int, proc: Path) -> str | None:
    try:
        return (proc / str(pid) / "comm").read_text().strip()
    except OSError:
        return None


def _give_back(original: dict[int, tuple[str, set[int]]], proc: Path) -> list[str]:
    failed = []
    for pid, (comm, cpus) in original.items():
        if _comm(pid, proc) != comm:  # gone (its pid may since name another task)
            continue
        try:
            os.sched_setaffinity(pid, cpus)
        except OSError as err:
            failed.append(f"{comm} (pid {pid}: {err.strerror})")
    return failed


def movable_kernel_threads(cpu: int, proc: Path = Path("/proc")) -> dict[int, tuple[str, set[int]]]:
    """The kernel threads that may run on ``cpu`` and on other CPUs, and whose CPUs may be changed: pid → (name,
    their CPUs)."""
    found: dict[int, tuple[str, set[int]]] = {}
    for entry in proc.iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
            flags = int(stat[stat.rindex(")") + 2:].split()[6])
            if not flags & PF_KTHREAD or flags & PF_NO_SETAFFINITY:
                continue
            cpus = os.sched_getaffinity(int(entry.name))
        except (OSError, ValueError, IndexError):
            continue
        if cpu in cpus and len(cpus) > 1:
            found[int(entry.name)] = (stat[stat.index("(") + 1:stat.rindex(")")], cpus)
    return found


def _undo_stale_threads(state_file: Path, proc: Path) -> tuple[int | None, str | None]:
    """A state file of moved threads left by another run: (its pid if that run is alive, else None after giving the
    threads back their CPUs; a warning naming those it could not)."""
    try:
        owner, *lines = state_file.read_text().splitlines()
        original = {int(pid): (comm, mask_cpus(mask)) for pid, mask, comm in (ln.split(" ", 2) for ln in lines)}
        holder = int(owner)
    except (OSError, ValueError):
        return None, None
    if holder != os.getpid() and _alive(holder):
        return holder, None
    failed = _give_back(original, proc)
    with contextlib.suppress(OSError):
        state_file.unlink()
    return None, (f"cannot give kernel threads a killed run moved their CPUs back: {', '.join(failed)}" if failed else None)


def move_kernel_threads_off(cpu: int, proc: Path = Path("/proc"),
                            state_file: Path = KERNEL_THREADS_STATE_FILE) -> tuple[MovedThreads | None, str | None]:
    """Move the kernel's housekeeping threads that may run elsewhere off ``cpu`` (``movable_kernel_threads``); returns
    (the moves held, or None; a warning naming why not, or None)."""
    holder, warning = _undo_stale_threads(state_file, proc)
    if holder is not None:
        return None, (f"another furuta-rt run (pid {holder}) holds the kernel's housekeeping threads off its CPU; this "
                      "run leaves them as they are")
    threads = movable_kernel_threads(cpu, proc)
    if not threads:
        return None, warning
    try:
        state_file.parent.mkdir(parents=True, exist_ok=True)
        state_file.write_text(f"{os.getpid()}\n" + "".join(f"{pid} {cpu_mask(cpus)} {comm}\n"
                                                           for pid, (comm, cpus) in threads.items()))
    except OSError as err:
        return None, f"cannot keep the kernel threads' CPUs in {state_file} ({err.strerror}); they stay where they are"
    moved: dict[int, tuple[str, set[int]]] = {}
    refused = []
    for pid, (comm, cpus) in threads.items():
        try:
            os.sched_setaffinity(pid, cpus - {cpu})
            moved[pid] = (comm, cpus)
        except OSError as err:
            refused.append(f"{comm} ({err.strerror})")
    held = MovedThreads(moved, state_file, proc)
    if not moved:
        held.restore()
        return None, (f"cannot move the kernel's housekeeping threads off CPU {cpu} ({refused[0]}): the tty's "
                      "kernel work may wait behind them. Fix: run as root")
    return held, warning
