"""One CPU for the loop, the device and the kernel's tty work (furuta_rt.cpu_placement): the kernel's CPU mask format,
the unbound work confined and put back, a killed run's confinement undone by the next, a run that holds it left
alone, and the one-line warnings where the system does not allow it. The real sysfs file is exercised where it is
writable (root); the rest on a stand-in file with the kernel's format."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from furuta_rt.cpu_placement import (
    WORKQUEUE_CPUMASK,
    confine_unbound_work,
    cpu_mask,
    mask_cpus,
    movable_kernel_threads,
    move_kernel_threads_off,
)


def test_the_kernels_mask_format_round_trips() -> None:
    assert cpu_mask({0}) == "1" and cpu_mask({1}) == "2" and cpu_mask({0, 1}) == "3" and cpu_mask({4, 8}) == "110"
    assert mask_cpus("3\n") == {0, 1} and mask_cpus("110") == {4, 8}
    assert mask_cpus("1,00000000") == {32}  # the kernel groups 32 CPUs per comma
    for cpus in ({0}, {2, 3}, {0, 5, 63}):
        assert mask_cpus(cpu_mask(cpus)) == cpus


def _files(tmp_path: Path, mask: str = "3") -> tuple[Path, Path]:
    mask_file = tmp_path / "cpumask"
    mask_file.write_text(mask + "\n")
    return mask_file, tmp_path / "run" / "state"


def test_confined_then_put_back_once(tmp_path: Path) -> None:
    mask_file, state = _files(tmp_path)
    held, warning = confine_unbound_work(1, mask_file, state)
    assert warning is None and held is not None
    assert mask_file.read_text() == "2"
    assert state.read_text().split() == [str(os.getpid()), "3"]  # the original, before the mask was changed
    assert held.restore() is None
    assert mask_file.read_text() == "3" and not state.exists()
    mask_file.write_text("1")  # someone else's change after ours was put back: a second restore does not undo it
    assert held.restore() is None and mask_file.read_text() == "1"


def _dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def test_a_killed_runs_confinement_is_undone_by_the_next(tmp_path: Path) -> None:
    mask_file, state = _files(tmp_path, "1")  # confined to CPU 0 by a run that was killed before it put it back
    state.parent.mkdir()
    state.write_text(f"{_dead_pid()} 3\n")
    held, warning = confine_unbound_work(1, mask_file, state)
    assert warning is None and held is not None
    assert held.original == "3", "the killed run's original, not its confinement, is what this run puts back"
    assert mask_file.read_text() == "2"
    held.restore()
    assert mask_file.read_text() == "3" and not state.exists()


def test_a_live_runs_confinement_is_left_alone(tmp_path: Path) -> None:
    mask_file, state = _files(tmp_path, "1")
    state.parent.mkdir()
    state.write_text(f"{os.getppid()} 3\n")  # a process that is alive: another run holding it
    held, warning = confine_unbound_work(1, mask_file, state)
    assert held is None and warning is not None and f"pid {os.getppid()}" in warning and "\n" not in warning
    assert mask_file.read_text() == "1\n" and state.read_text() == f"{os.getppid()} 3\n"


def test_what_the_system_does_not_allow_is_one_line(tmp_path: Path) -> None:
    held, warning = confine_unbound_work(0, tmp_path / "missing", tmp_path / "state")
    assert held is None and warning is not None and "no " in warning and "\n" not in warning
    mask_file, state = _files(tmp_path, "2")
    held, warning = confine_unbound_work(0, mask_file, state)  # CPU 0 is not among the unbound work's CPUs
    assert held is None and "CPU 0 is not among" in str(warning) and mask_file.read_text() == "2\n"
    assert not state.exists()
    unwritable = tmp_path / "dir-mask"
    unwritable.mkdir()  # reading or writing a directory fails as an unwritable sysfs file does
    held, warning = confine_unbound_work(0, unwritable, tmp_path / "state2")
    assert held is None and warning is not None and "\n" not in warning and not (tmp_path / "state2").exists()


def test_pinning_the_calling_thread_and_refusing_an_absent_cpu() -> None:
    allowed = sorted(os.sched_getaffinity(0))
    code = ("import os; from furuta_rt.cpu_placement import pin_cpu; "
            f"print(pin_cpu({allowed[0]}), sorted(os.sched_getaffinity(0)), pin_cpu(4096))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.startswith(f"({allowed[0]}, None) [{allowed[0]}] (None, 'CPU 4096 is not available"), out


@pytest.mark.skipif(not os.access(WORKQUEUE_CPUMASK, os.W_OK) or len(os.sched_getaffinity(0)) < 2,
                    reason="needs root and two CPUs: the kernel's own mask")
def test_the_kernel_takes_the_mask_and_gets_its_own_back(tmp_path: Path) -> None:
    before = WORKQUEUE_CPUMASK.read_text().strip()
    cpu = sorted(mask_cpus(before))[-1]
    held, warning = confine_unbound_work(cpu, WORKQUEUE_CPUMASK, tmp_path / "state")
    try:
        assert warning is None and held is not None
        assert mask_cpus(WORKQUEUE_CPUMASK.read_text()) == {cpu}
    finally:
        if held is not None:
            held.restore()
    assert WORKQUEUE_CPUMASK.read_text().strip() == before


def test_kernel_threads_a_killed_run_moved_get_their_cpus_back_from_its_state_file(tmp_path: Path) -> None:
    """The state file names each moved thread with its CPUs; a dead owner's moves are undone, a live owner's are
    left, and a pid that now names another task is not touched."""
    state = tmp_path / "state"
    me = os.getpid()
    mine = sorted(os.sched_getaffinity(0))
    proc = tmp_path / "proc"  # a stand-in /proc that names this process only (no kernel threads to move)
    (proc / str(me)).mkdir(parents=True)
    (proc / str(me) / "comm").write_text(Path(f"/proc/{me}/comm").read_text())
    code = "import time; time.sleep(30)"
    owner = subprocess.Popen([sys.executable, "-c", code])
    try:
        state.write_text(f"{owner.pid}\n{me} {cpu_mask(set(mine))} {Path(f'/proc/{me}/comm').read_text().strip()}\n")
        held, warning = move_kernel_threads_off(mine[-1], state_file=state)
        assert held is None and warning is not None and f"pid {owner.pid}" in warning and "\n" not in warning
        assert state.exists()
    finally:
        owner.kill()
        owner.wait()
    if len(mine) > 1:  # the owner is gone: this process (named in its file) gets the CPUs it lists
        os.sched_setaffinity(0, {mine[0]})
        try:
            move_kernel_threads_off(mine[-1], proc=proc, state_file=state)
            assert sorted(os.sched_getaffinity(0)) == mine and not state.exists()
        finally:
            os.sched_setaffinity(0, mine)
    state.write_text(f"{owner.pid}\n{me} {cpu_mask({mine[0]})} not-this-process\n")
    os.sched_setaffinity(0, set(mine))
    move_kernel_threads_off(mine[-1], proc=proc, state_file=state)
    assert sorted(os.sched_getaffinity(0)) == mine and not state.exists()  # another name: left alone


@pytest.mark.skipif(os.geteuid() != 0 or len(os.sched_getaffinity(0)) < 2 or not movable_kernel_threads(
    sorted(os.sched_getaffinity(0))[-1]), reason="needs root, two CPUs and kernel threads that may move")
def test_the_kernels_housekeeping_threads_leave_the_cpu_and_come_back(tmp_path: Path) -> None:
    cpu = sorted(os.sched_getaffinity(0))[-1]
    before = movable_kernel_threads(cpu)
    held, warning = move_kernel_threads_off(cpu, state_file=tmp_path / "state")
    try:
        assert warning is None and held is not None and set(held.original) == set(before)
        assert movable_kernel_threads(cpu) == {}
        assert all(cpu not in os.sched_getaffinity(pid) for pid in before)
        owner, *lines = (tmp_path / "state").read_text().splitlines()
        assert int(owner) == os.getpid() and len(lines) == len(before)
    finally:
        if held is not None:
            held.restore()
    assert movable_kernel_threads(cpu) == before and not (tmp_path / "state").exists()
