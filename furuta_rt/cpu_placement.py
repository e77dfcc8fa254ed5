"""Where the real-time threads run: one CPU for the loop, the device it talks to and the kernel's tty work.

``pin_cpu`` pins the calling thread (the control loop; hil-mock's device thread). ``confine_unbound_work`` moves the
kernel's unbound work to that CPU.

Bytes written to a pseudo-terminal (and bytes a USB-serial adapter receives) reach the reader through a kernel work
item (``flush_to_ldisc``) on an *unbound* workqueue, run by a normal-priority kworker on whichever CPU the scheduler
picks, usually an idle one. So each period of a SAMPLE → COMMAND round trip wakes CPUs besides the loop's: a virtual
CPU its hypervisor is not running at that moment wakes milliseconds later, and the period is missed. With the loop
(and, with ``--mock``, the device) pinned to one CPU and the unbound work confined to it too, a round trip needs no
other CPU: what remains is that one CPU's own stalls, the floor a lone SCHED_FIFO thread measures.

The mask (``/sys/devices/virtual/workqueue/cpumask``) is machine-wide: it moves all unbound kernel work, not only the
tty's. So it is changed only on request (``furuta-rt run --cpu N``), put back when the run ends, and the original is
kept in a state file first, so that a run killed before it could put the mask back (SIGKILL) is undone by the next
run that confines it.
"""

from __future__ import annotations

import contextlib
import os
from dataclasses import dataclass
from pathlib import Path

from furuta_rt.errors import UserError

WORKQUEUE_CPUMASK = Path("/sys/devices/virtual/workqueue/cpumask")
STATE_FILE = Path("/run/furuta-rt/unbound-work-cpumask")


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
