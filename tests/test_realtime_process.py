"""What the real-time control process of `furuta-rt run` holds, seen from outside while it balances (/proc): none
of scipy's or matplotlib's shared libraries (the gains and the observer's matrices are made in a helper process
that is gone by then), and no OpenBLAS worker threads. mlockall would lock all of it for the whole run; its size
is measured by scripts/bench's memory section, not here."""

from __future__ import annotations

import signal
import time
from pathlib import Path

from test_reliability_harness import DaemonProcess, traceback_free


def _mapped_files(pid: int) -> set[str]:
    files = set()
    for line in Path(f"/proc/{pid}/maps").read_text().splitlines():
        parts = line.split(maxsplit=5)
        if len(parts) == 6 and parts[5].startswith("/"):
            files.add(parts[5])
    return files


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def test_the_control_process_holds_no_scipy_and_no_blas_threads(tmp_path: Path) -> None:
    daemon = DaemonProcess(["--mock", "--no-tui", "--duration", "60", "--log", str(tmp_path / "run.mcap")])
    try:
        daemon.wait_for_line("→ balancing")
        time.sleep(0.5)
        mapped = _mapped_files(daemon.pid)
        threads = [Path(f"{task}/comm").read_text().strip() for task in Path(f"/proc/{daemon.pid}/task").iterdir()]
        children = [_cmdline(pid) for pid in daemon.children()]
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
    spawned = [c for c in children if "spawn_main" in c]
    assert len(spawned) == 1 and sum("hil_mock" in c for c in children) == 1, \
        f"the logger and the mock run beside it, the design helper has ended: {children}"
