"""What the real-time control process of `furuta-rt run` holds, seen from outside while it balances (/proc): none
of scipy's or matplotlib's shared libraries (the gains and the observer's matrices are made in a helper process
that is gone by then), and no OpenBLAS worker threads. mlockall would lock all of it for the whole run; its size
is measured by scripts/bench's memory section, not here."""

from __future__ import annotations

import contextlib
import os
import signal
import time
from pathlib import Path

import pytest
from test_reliability_harness import DaemonProcess, traceback_free

from furuta_rt.cpu_idle import CPU_LATENCY_DEVICE, current_wakeup_latency_us
from furuta_rt.cpu_placement import (
    KERNEL_THREADS_STATE_FILE,
    STATE_FILE,
    WORKQUEUE_CPUMASK,
    mask_cpus,
    movable_kernel_threads,
)


def _mapped_files(pid: int) -> set[str]:
    files = set()
    for line in Path(f"/proc/{pid}/maps").read_text().splitlines():
        parts = line.split(maxsplit=5)
        if len(parts) == 6 and parts[5].startswith("/"):
            files.add(parts[5])
    return files


def _open_files(pid: int) -> set[str]:
    out = set()
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        with contextlib.suppress(OSError):  # closed since the listing
            out.add(os.readlink(fd))
    return out


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def test_the_control_process_holds_no_scipy_and_no_blas_threads_and_keeps_idle_cpus_awake(tmp_path: Path) -> None:
    daemon = DaemonProcess(["--mock", "--no-tui", "--duration", "60", "--log", str(tmp_path / "run.mcap")])
    try:
        daemon.wait_for_line("→ balancing")
        time.sleep(0.5)
        mapped = _mapped_files(daemon.pid)
        threads = [Path(f"{task}/comm").read_text().strip() for task in Path(f"/proc/{daemon.pid}/task").iterdir()]
        children = [_cmdline(pid) for pid in daemon.children()]
        qos_holders = [pid for pid in (daemon.pid, *daemon.children()) if CPU_LATENCY_DEVICE in _open_files(pid)]
        bound_us = current_wakeup_latency_us()
        daemon.kill_group(signal.SIGINT)
        rc = daemon.wait()
    finally:
        daemon.kill_group(signal.SIGKILL)
    assert rc == 0 and traceback_free(daemon.stderr), daemon.stderr
    assert any("numpy" in f for f in mapped), "the maps were not read from the control process"
    heavy = sorted(f for f in mapped if {"scipy", "scipy.libs", "matplotlib", "matplotlib.libs"} & set(Path(f).parts))
    assert not heavy, heavy
    # the loop, the log queue's feeder, the logger's watcher: no OpenBLAS workers (one per core, a locked buffer each)
    assert len(threads) <= 3, threads
    # idle CPUs wake at once while it runs: the control process and the real-time mock hold the PM QoS request
    if os.access(CPU_LATENCY_DEVICE, os.W_OK):
        assert daemon.pid in qos_holders and len(qos_holders) == 2 and bound_us == 0, (qos_holders, bound_us)
        assert "idle CPUs wake at once (PM QoS 0 µs)" in daemon.stderr
    else:
        assert f"warning: {CPU_LATENCY_DEVICE} is not writable" in daemon.stderr
    spawned = [c for c in children if "spawn_main" in c]
    assert len(spawned) == 1 and sum("hil_mock" in c for c in children) == 1, \
        f"the logger and the mock run beside it, the design helper has ended: {children}"


def _allowed_cpus(pid: int, tid: int | None = None) -> set[int]:
    return set(os.sched_getaffinity(tid if tid is not None else pid))


def _fifo_thread(pid: int) -> int:
    """The SCHED_FIFO thread of ``pid`` (the loop, the device's serving thread)."""
    for task in Path(f"/proc/{pid}/task").iterdir():
        if os.sched_getscheduler(int(task.name)) & ~getattr(os, "SCHED_RESET_ON_FORK", 0) == os.SCHED_FIFO:
            return int(task.name)
    raise AssertionError(f"no SCHED_FIFO thread in {pid}")


@pytest.mark.skipif(not os.access(WORKQUEUE_CPUMASK, os.W_OK) or len(os.sched_getaffinity(0)) < 2,
                    reason="needs root (the kernel's unbound work mask) and two CPUs")
def test_one_cpu_for_the_loop_the_device_and_the_ttys_kernel_work(tmp_path: Path) -> None:
    """`run --cpu N`: the loop and hil-mock's device thread on CPU N, the kernel's unbound work (the pty's flush work)
    confined there while it runs, the kernel's housekeeping threads and the logger kept off it; the mask and the
    threads' CPUs put back at the end — and after a SIGKILL, which leaves them changed, by the next run."""
    # the mask before any run: a run killed earlier may have left it confined, with the original in its state file
    before = STATE_FILE.read_text().split()[1] if STATE_FILE.exists() else WORKQUEUE_CPUMASK.read_text().strip()
    cpu = sorted(mask_cpus(before) & os.sched_getaffinity(0))[-1]
    housekeeping = movable_kernel_threads(cpu)  # pid → (name, CPUs) before the run (or before a killed one)
    if KERNEL_THREADS_STATE_FILE.exists():
        housekeeping |= {int(pid): (name, mask_cpus(mask)) for pid, mask, name in
                         (line.split(" ", 2) for line in KERNEL_THREADS_STATE_FILE.read_text().splitlines()[1:])}
    daemon = DaemonProcess(["--mock", "--no-tui", "--duration", "60", "--cpu", str(cpu), "--log", str(tmp_path / "a.mcap")])
    try:
        daemon.wait_for_line("→ balancing")
        during = mask_cpus(WORKQUEUE_CPUMASK.read_text())
        state = STATE_FILE.read_text().split()
        loop_cpus = _allowed_cpus(daemon.pid, _fifo_thread(daemon.pid))
        mock = [p for p in daemon.children() if "hil_mock" in _cmdline(p)]
        device_cpus = _allowed_cpus(mock[0], _fifo_thread(mock[0]))
        logger_cpus = [_allowed_cpus(p) for p in daemon.spawned()]
        kernel_threads_during = {pid: _allowed_cpus(pid) for pid in housekeeping}
        daemon.kill_group(signal.SIGINT)
        rc = daemon.wait()
    finally:
        daemon.kill_group(signal.SIGKILL)
    assert rc == 0 and traceback_free(daemon.stderr), daemon.stderr
    assert f"pinned to CPU {cpu}, the kernel's tty work on CPU {cpu} too" in daemon.stderr
    assert during == {cpu} and state == [str(daemon.pid), before]
    assert loop_cpus == {cpu} and device_cpus == {cpu}, (loop_cpus, device_cpus)
    assert len(logger_cpus) == 1 and cpu not in logger_cpus[0], logger_cpus
    assert f"realtime, fifo priority, CPU {cpu})" in daemon.stdout
    assert housekeeping and all(cpu not in c for c in kernel_threads_during.values()), kernel_threads_during
    assert WORKQUEUE_CPUMASK.read_text().strip() == before and not STATE_FILE.exists()
    assert {pid: _allowed_cpus(pid) for pid in housekeeping} == {p: c for p, (_, c) in housekeeping.items()}
    assert not KERNEL_THREADS_STATE_FILE.exists()

    killed = DaemonProcess(["--mock", "--no-tui", "--duration", "60", "--cpu", str(cpu)])
    try:
        killed.wait_for_line("→ balancing")
        killed.kill_group(signal.SIGKILL)
        killed.wait()
    finally:
        killed.kill_group(signal.SIGKILL)
    assert mask_cpus(WORKQUEUE_CPUMASK.read_text()) == {cpu}, "a killed run cannot put the mask back itself"
    assert all(cpu not in _allowed_cpus(pid) for pid in housekeeping), "nor the threads' CPUs"
    after = DaemonProcess(["--mock", "--no-tui", "--duration", "1", "--cpu", str(cpu)])
    try:
        assert after.wait() == 0, after.stderr
    finally:
        after.kill_group(signal.SIGKILL)
    assert WORKQUEUE_CPUMASK.read_text().strip() == before and not STATE_FILE.exists()
    assert {pid: _allowed_cpus(pid) for pid in housekeeping} == {p: c for p, (_, c) in housekeeping.items()}


# ------------------------------------------------------------------ the controller design kept between runs
def _same_design(a: object, b: object) -> bool:
    """Bit for bit: the gains and every matrix of the observer."""
    import dataclasses

    import numpy as np

    fields = [f.name for f in dataclasses.fields(a.observer)]  # type: ignore[attr-defined]
    return np.array_equal(a.gains, b.gains) and all(  # type: ignore[attr-defined]
        np.array_equal(getattr(a.observer, f), getattr(b.observer, f)) for f in fields)  # type: ignore[attr-defined]


def test_a_kept_design_is_the_helpers_bit_for_bit_and_starts_no_helper(tmp_path: Path, monkeypatch) -> None:
    """The first run of a rig makes its design in the helper and keeps it; the next one starts no helper and gets
    the same arrays, which are those ``controller_design`` makes in-process (another rig value or other gains are
    another key: the next test). A torn file is made again (and replaced); FURUTA_RT_DESIGN_CACHE=0 uses none."""
    from furuta_rt.config import load_rig
    from furuta_rt.controller.controller import controller_design
    from furuta_rt.runtime.design_process import DesignProcess

    monkeypatch.setenv("FURUTA_RT_BUILD_DIR", str(tmp_path))
    rig = load_rig("thesis")
    first = DesignProcess(rig, None)
    assert not first.kept
    made = first.result()
    kept_files = list((tmp_path / "designs").glob("design-*.npz"))
    assert len(kept_files) == 1
    second = DesignProcess(rig, None)
    assert second.kept and _same_design(second.result(), made) and _same_design(made, controller_design(rig))
    assert isinstance(second.result().observer.R, float)
    # a torn file: made again by a helper, and replaced
    kept_files[0].write_bytes(kept_files[0].read_bytes()[:100])
    torn = DesignProcess(rig, None)
    assert not torn.kept and _same_design(torn.result(), made)
    assert DesignProcess(rig, None).kept
    monkeypatch.setenv("FURUTA_RT_DESIGN_CACHE", "0")
    off = DesignProcess(rig, None)
    assert not off.kept
    off.close()
    # a source this process may not read (a clone in another user's private folder): no key, the helper makes it
    from furuta_rt.runtime import design_process

    def unreadable(*_: object) -> str:
        raise PermissionError(13, "Permission denied", str(design_process.PACKAGE_DIR))

    monkeypatch.delenv("FURUTA_RT_DESIGN_CACHE")
    monkeypatch.setattr(design_process, "design_key", unreadable)
    blind = DesignProcess(rig, None)
    assert not blind.kept
    blind.close()


def test_the_design_key_follows_the_rig_the_gains_and_the_source(tmp_path: Path, monkeypatch) -> None:
    """Any rig value, the gains, or one byte of furuta_rt's source gives another key: a kept design is never one
    an edited controller or model would compute differently."""
    import shutil

    from furuta_rt.config import load_rig
    from furuta_rt.runtime import design_process

    rig = load_rig("thesis")
    key = design_process.design_key(rig, None)
    assert design_process.design_key(load_rig("thesis"), None) == key
    plant = rig.plant.model_copy(update={"m": rig.plant.m * 1.001})
    assert design_process.design_key(rig.model_copy(update={"plant": plant}), None) != key
    faster = rig.model_copy(update={"control": rig.control.model_copy(update={"rate_hz": 1000.0})})
    assert design_process.design_key(faster, None) != key  # the observer is discretised at the period
    assert design_process.design_key(rig, [1.0, 2.0, 3.0, 4.0]) != key
    copy = tmp_path / "furuta_rt"
    shutil.copytree(design_process.PACKAGE_DIR, copy, ignore=shutil.ignore_patterns("__pycache__"))
    monkeypatch.setattr(design_process, "PACKAGE_DIR", copy)
    assert design_process.design_key(rig, None) == key
    with (copy / "controller" / "observer.py").open("a") as f:
        f.write("\n")
    assert design_process.design_key(rig, None) != key
