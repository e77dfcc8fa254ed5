"""Hostile files and the files of a running log, through the real CLI (subprocesses): FIFOs, /dev/zero,
symbolic-link loops, nesting beyond the parsers' recursion, a CSV cell over the csv module's limit, a sparse
file with the MCAP magic; a repair through a symbolic link; a log a run is writing (locked) and a log deleted
under a run. Each: one line naming the file, exit 2 (3 for a run whose log is gone), no traceback, in
bounded time — a FIFO or /dev/zero that hangs or eats memory fails by the subprocess timeout."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
from test_reliability_harness import (
    FURUTA_RT,
    ROOT,
    DaemonProcess,
    MockProcess,
    independent_mcap_counts,
    read_summary,
    start_daemon,
    traceback_free,
    wait_until_locked,
    write_test_rig,
)

from furuta_rt.io.mcap_read import read_log

TIMEOUT_S = 45  # a hang (FIFO) or an unbounded read (/dev/zero, a 2 GB sparse file) runs into it


def _cli(*args: str, timeout: float = TIMEOUT_S) -> subprocess.CompletedProcess:
    return subprocess.run([*FURUTA_RT, *args], capture_output=True, text=True, cwd=ROOT, timeout=timeout,
                          stdin=subprocess.DEVNULL)


def _one_line(proc: subprocess.CompletedProcess, *needles: str, code: int = 2) -> None:
    err = proc.stderr.strip()
    assert traceback_free(err + proc.stdout), err
    assert proc.returncode == code, (proc.returncode, err)
    assert len(err.splitlines()) == 1, err
    for n in needles:
        assert n in err, err


def _recording_csv(path: Path, n: int = 20000) -> Path:
    t = np.arange(n) / 500.0
    data = np.column_stack([t, 0.01 * np.sin(3 * t), 0.2 * np.sin(t), 0.05 * np.cos(5 * t)])
    np.savetxt(path, data, delimiter=",", header="t,theta,phi,u", comments="", fmt="%.6f")
    return path


@pytest.fixture
def files(tmp_path: Path) -> dict[str, Path]:
    fifo = tmp_path / "fifo.csv"
    os.mkfifo(fifo)
    loop = tmp_path / "loop.mcap"
    os.symlink(tmp_path / "loop2.mcap", loop)
    os.symlink(loop, tmp_path / "loop2.mcap")
    deep_json = tmp_path / "deep.json"
    deep_json.write_text("[" * 200_000 + "]" * 200_000)
    deep_toml = tmp_path / "deep.toml"
    deep_toml.write_text("a = " + "[" * 200_000 + "]" * 200_000 + "\n")
    wide = tmp_path / "wide.csv"
    wide.write_text("t,theta,phi,u\n0," + "1" * (200 * 1024) + ",0,0\n0.002,0,0,0\n")
    sparse = tmp_path / "sparse.mcap"
    with sparse.open("wb") as fh:
        fh.write(b"\x89MCAP0\r\n")
        fh.truncate(2 * 1024**3)  # 2 GB of zeros after the magic, no disk used
    return {"fifo": fifo, "loop": loop, "deep_json": deep_json, "deep_toml": deep_toml, "wide": wide,
            "sparse": sparse, "tmp": tmp_path}


CASES = {
    "replay a FIFO": (["replay", "{fifo}"], "FIFO"),
    "convert a FIFO": (["convert", "{fifo}", "-o", "{tmp}/o.mcap"], "FIFO"),
    "diagnose a FIFO": (["diagnose", "{fifo}"], "FIFO"),
    "run --comp-from a FIFO": (["run", "--mock", "--no-tui", "--comp-from", "{fifo}"], "FIFO"),
    "diagnose /dev/zero": (["diagnose", "/dev/zero"], "character device"),
    "convert /dev/zero": (["convert", "/dev/zero", "-o", "{tmp}/o.mcap"], "character device"),
    "replay /dev/zero": (["replay", "/dev/zero"], "character device"),
    "run --comp-from /dev/zero": (["run", "--mock", "--no-tui", "--comp-from", "/dev/zero"], "character device"),
    "replay a link loop": (["replay", "{loop}"], "symbolic link loop"),
    "diagnose a link loop": (["diagnose", "{loop}"], "symbolic link loop"),
    "repair a link loop": (["repair", "{loop}"], "symbolic link loop"),
    "convert to a link loop": (["convert", "{wide}", "-o", "{loop}"], "symbolic link loop"),
    "run --log a link loop": (["run", "--mock", "--no-tui", "--log", "{loop}"], "symbolic link loop"),
    "run --comp-from deep JSON": (["run", "--mock", "--no-tui", "--comp-from", "{deep_json}"], "nested too deeply"),
    "run --config deep TOML": (["run", "--mock", "--no-tui", "--config", "{deep_toml}"], "nested too deeply"),
    "diagnose a CSV cell over 128 KiB": (["diagnose", "{wide}"], "wide.csv"),
    "convert a CSV cell over 128 KiB": (["convert", "{wide}", "-o", "{tmp}/o.mcap"], "wide.csv"),
    "replay a 2 GB sparse MCAP": (["replay", "{sparse}"], "sparse.mcap"),
    "repair a 2 GB sparse MCAP": (["repair", "{sparse}"], "sparse.mcap"),
}


@pytest.mark.parametrize("case", list(CASES))
def test_a_hostile_input_is_one_line_exit_2_in_bounded_time(files: dict[str, Path], case: str) -> None:
    argv, needle = CASES[case]
    proc = _cli(*[a.format(**files) for a in argv])
    _one_line(proc, needle)


def test_repair_through_a_symlink_keeps_the_original_bytes_beside_the_target_and_the_link(tmp_path: Path) -> None:
    good = tmp_path / "good.mcap"
    proc = _cli("convert", str(_recording_csv(tmp_path / "rec.csv")), "-o", str(good))
    assert proc.returncode == 0, proc.stderr
    target_dir = tmp_path / "data"
    target_dir.mkdir()
    target = target_dir / "run.mcap"
    torn = good.read_bytes()[: good.stat().st_size * 2 // 3]  # a killed run: no summary, a torn record
    target.write_bytes(torn)
    link = tmp_path / "link.mcap"
    link.symlink_to(target)
    proc = _cli("repair", str(link))
    assert proc.returncode == 0, proc.stderr
    assert link.is_symlink() and os.readlink(link) == str(target), "the link is left as it was"
    bak = target_dir / "run.mcap.bak"
    assert bak.is_file() and not bak.is_symlink() and bak.read_bytes() == torn, "the original bytes, as a real file"
    assert not (tmp_path / "link.mcap.bak").exists()
    assert str(bak) in proc.stdout, proc.stdout
    assert not read_log(link).recovered  # the repaired file, read through the link, is complete


def test_a_log_being_written_is_locked_against_force_repair_and_a_second_run(tmp_path: Path) -> None:
    mock = MockProcess(tmp_path, [])
    daemon = start_daemon(tmp_path, mock.port, duration=60.0)
    log = tmp_path / "run.mcap"
    try:
        daemon.wait_for_line("→ balancing")
        wait_until_locked(log)  # the logger opens the file after the handshake, in its own time
        second = _cli("run", "--mock", "--no-tui", "--duration", "2", "--force", "--log", str(log),
                      "--summary-json", str(tmp_path / "second.json"))
        _one_line(second, "being written", str(log))
        rep = _cli("repair", str(log))
        _one_line(rep, "being written", str(log))
        rep_force = _cli("repair", "--force", str(log))
        _one_line(rep_force, "being written")
        daemon.kill_group(signal.SIGINT)
        rc = daemon.wait()
    finally:
        daemon.kill_group(signal.SIGKILL)
        mock.stop()
    assert rc == 0, daemon.stderr
    data = read_log(log)
    assert not data.recovered, data.warnings
    assert data.n_ticks == read_summary(tmp_path)["log_ticks"]
    assert not (tmp_path / "run.mcap.bak").exists()


def test_a_log_deleted_under_a_running_run_is_said_at_once_and_the_run_exits_3(tmp_path: Path) -> None:
    mock = MockProcess(tmp_path, [])
    daemon = start_daemon(tmp_path, mock.port, duration=60.0)
    try:
        daemon.wait_for_line("→ balancing")
        wait_until_locked(tmp_path / "run.mcap")  # the logger has it open (it opens it in its own time)
        (tmp_path / "run.mcap").unlink()
        line = daemon.wait_for_line("was deleted", timeout=30)  # said while the run goes on
        assert daemon.proc.poll() is None, "the run went on"
        daemon.kill_group(signal.SIGINT)
        rc = daemon.wait()
    finally:
        daemon.kill_group(signal.SIGKILL)
        mock.stop()
    assert "run.mcap" in line
    assert traceback_free(daemon.stderr + daemon.stdout), daemon.stderr
    assert rc == 3, daemon.stderr
    assert not (tmp_path / "run.mcap").exists()


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP, signal.SIGINT], ids=["SIGTERM", "SIGHUP", "SIGINT"])
def test_a_convert_stopped_by_a_signal_leaves_no_partial_file(tmp_path: Path, sig: int) -> None:
    src = _recording_csv(tmp_path / "rec.csv", n=400_000)
    out = tmp_path / "out.mcap"
    proc = subprocess.Popen([*FURUTA_RT, "convert", str(src), "-o", str(out)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=ROOT, start_new_session=True)
    try:
        end = time.monotonic() + TIMEOUT_S
        while not list(tmp_path.glob(".*partial*")) and proc.poll() is None and time.monotonic() < end:
            time.sleep(0.005)
        assert proc.poll() is None, "convert ended before it began writing"
        os.killpg(proc.pid, sig)
        _, err = proc.communicate(timeout=TIMEOUT_S)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert traceback_free(err), err
    assert proc.returncode == 128 + sig, err
    assert len(err.strip().splitlines()) == 1 and "interrupted" in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec.csv"], "a .partial (or a half output) was left"


def test_two_runs_started_together_on_one_log_the_loser_claims_none_of_its_ticks(tmp_path: Path) -> None:
    """Started together, both may pass the start-up check (the log does not exist yet): the logger that creates it
    first wins (O_EXCL), and the loser says it could not write the log, exits 3 and counts 0 ticks in it, not the
    winner's. Which of the races the loser loses depends on the machine's load: when the winner's logger created the
    file before the loser's check, or the loser's logger failed before its first tick, the loser is refused in start-up
    (exit 2, its last line naming the file) instead."""
    shared = tmp_path / "shared.mcap"
    mocks = []
    for name in ("a", "b"):
        (tmp_path / name).mkdir()
        mocks.append((tmp_path / name, MockProcess(tmp_path / name, [])))
    rigs = [write_test_rig(d) for d, _ in mocks]
    runs = [(d, mock, start_daemon(d, mock.port, duration=3.0, rig=rig, extra=["--log", str(shared)]))
            for (d, mock), rig in zip(mocks, rigs, strict=True)]
    codes = {}
    try:
        for d, _, daemon in runs:
            codes[d.name] = daemon.wait()
    finally:
        for _, mock, daemon in runs:
            daemon.kill_group(signal.SIGKILL)
            mock.stop()
    assert sorted(codes.values()) in ([0, 2], [0, 3]), {d.name: daemon.stderr for d, _, daemon in runs}
    winner = next(d for d in codes if codes[d] == 0)
    loser = next(d for d in codes if codes[d] != 0)
    loser_err = next(daemon.stderr for d, _, daemon in runs if d.name == loser)
    assert traceback_free(loser_err) and "shared.mcap" in loser_err
    if codes[loser] == 3:  # lost the logger's race: ran, and claims none of the winner's ticks
        assert read_summary(tmp_path / loser)["log_ticks"] == 0
    else:  # refused in start-up (at the check, or its logger lost the race before the first tick): no tick claimed
        assert "exists" in loser_err.strip().splitlines()[-1], loser_err
        summary = tmp_path / loser / "summary.json"
        assert not summary.exists() or read_summary(tmp_path / loser)["log_ticks"] == 0
    assert read_summary(tmp_path / winner)["log_ticks"] == read_log(shared).n_ticks > 0


def _padded_log(tmp_path: Path, records: int) -> tuple[Path, int]:
    """A real simulated log with ``records`` empty records of MCAP's user range (opcode 0x80, which readers skip)
    after its header: the same ticks, but reading it takes long enough for another process to cut it meanwhile.
    Returns (path, the byte offset where the padding starts)."""
    from furuta_rt.config import load_rig
    from furuta_rt.replay.simulate import simulate_log

    plain = simulate_log(tmp_path / "plain.mcap", load_rig("thesis"), 0.5, substep_hz=1000, flush_every=0.1)
    data = plain.read_bytes()
    header_end = 8 + 9 + int.from_bytes(data[9:17], "little")  # the magic, then the Header record
    padded = tmp_path / "run.mcap"
    padded.write_bytes(data[:header_end] + (b"\x80" + bytes(8)) * records + data[header_end:])
    return padded, header_end


def _has_open(pid: int, path: Path) -> bool:
    try:
        fds = os.listdir(f"/proc/{pid}/fd")
    except OSError:
        return False
    for fd in fds:
        try:
            if os.readlink(f"/proc/{pid}/fd/{fd}") == str(path):
                return True
        except OSError:
            continue
    return False


def test_a_log_cut_short_while_replay_reads_it_is_one_line_exit_2_not_a_bus_error(tmp_path: Path) -> None:
    """Another process truncates the log while `replay` reads it (caught with the file open, the reader stopped by
    SIGSTOP so the cut lands mid-read): one line naming the file, exit 2, no --csv written. Read through a memory
    map, touching the pages past the new end was SIGBUS: exit 135, no message."""
    log, pad_start = _padded_log(tmp_path, 600_000)
    assert read_log(log).n_ticks == read_log(tmp_path / "plain.mcap").n_ticks > 0  # the padding is harmless
    out = tmp_path / "out.csv"
    proc = subprocess.Popen([*FURUTA_RT, "replay", str(log), "--csv", str(out)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=ROOT, stdin=subprocess.DEVNULL)
    try:
        end = time.monotonic() + TIMEOUT_S
        while not _has_open(proc.pid, log) and proc.poll() is None and time.monotonic() < end:
            time.sleep(0.001)
        time.sleep(0.05)  # into the records (the read takes seconds): past opening it, whatever reads it
        os.kill(proc.pid, signal.SIGSTOP)
        assert _has_open(proc.pid, log), "replay was not caught reading the log (it read 5 MB of records first)"
        subprocess.run(["truncate", "-s", str(pad_start + 9 * 1000), str(log)], check=True, timeout=TIMEOUT_S)
        os.kill(proc.pid, signal.SIGCONT)
        stdout, stderr = proc.communicate(timeout=TIMEOUT_S)
    finally:
        if proc.poll() is None:
            proc.kill()
    _one_line(subprocess.CompletedProcess(proc.args, proc.returncode, stdout, stderr), "shrank", str(log))
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["plain.mcap", "run.mcap"]


HELPER_ALWAYS = {**os.environ, "FURUTA_RT_DESIGN_CACHE": "0"}
"""A run's environment where its controller design helper always starts (no design kept from an earlier run): the
start-up tests below find the logger as the second 'spawn' child, beside the helper."""


def _spawned(daemon: DaemonProcess) -> list[int]:
    """pids of the daemon's 'spawn' children in the order they started: the controller's design helper (first, gone
    before the first tick), then the logger."""
    spawned = []
    for pid in daemon.children():
        try:
            if b"spawn_main" in Path(f"/proc/{pid}/cmdline").read_bytes():
                started = int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[19])
                spawned.append((started, pid))
        except (OSError, ValueError, IndexError):
            continue
    return [pid for _, pid in sorted(spawned)]


def _logger_pid(daemon: DaemonProcess, *, starting: bool) -> int | None:
    """pid of the daemon's logger once it exists (``starting``: once the design helper and it both run)."""
    spawned = _spawned(daemon)
    return spawned[-1] if len(spawned) >= (2 if starting else 1) else None


def _refused_in_start_up(daemon: DaemonProcess, rc: int | None, cause: str) -> str:
    """A start-up that lost one of its processes: exit 2, no traceback, one error line naming ``cause``, never
    balanced. Returns the daemon's output."""
    out = daemon.stderr + daemon.stdout
    assert traceback_free(out), out
    assert rc == 2, out
    errors = [line for line in daemon.stderr.splitlines() if "error" in line]
    assert len(errors) == 1 and cause in errors[0], out
    assert "balancing" not in out
    return out


def _starting_logger(daemon: DaemonProcess) -> int | None:
    """Wait (up to TIMEOUT_S, while the daemon lives) until its logger starts beside the design helper: its pid."""
    end = time.monotonic() + TIMEOUT_S
    while (logger := _logger_pid(daemon, starting=True)) is None and daemon.proc.poll() is None and time.monotonic() < end:
        time.sleep(0.001)
    return logger


def test_the_loser_of_a_race_for_the_live_view_port_says_so_and_advertises_nothing(tmp_path: Path) -> None:
    """The port is free when the run checks it, and taken (here by a listener standing for another run) before the
    run's logger binds it: the run must not print "live view on ws://…" (that is the other program's view) — one
    line naming the port, exit 2, before the device streams; the log holds no tick."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    log = tmp_path / "run.mcap"
    daemon = DaemonProcess(["--mock", "--no-tui", "--duration", "5", "--log", str(log), f"--foxglove={port}"],
                           env=HELPER_ALWAYS)
    winner = socket.socket()
    try:
        logger = _starting_logger(daemon)
        assert logger is not None, daemon.stderr
        os.kill(logger, signal.SIGSTOP)  # past the run's port check, before its live view binds (seconds of imports)
        winner.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        winner.bind(("127.0.0.1", port))
        winner.listen()
        os.kill(logger, signal.SIGCONT)
        rc = daemon.wait()
    finally:
        daemon.kill_group(signal.SIGKILL)
        winner.close()
    out = daemon.stderr + daemon.stdout
    assert traceback_free(out), out
    assert "live view on" not in out, out
    assert rc == 2, out
    errors = [line for line in daemon.stderr.splitlines() if "error" in line]
    assert len(errors) == 1 and f"--foxglove={port}" in errors[0] and "took the port" in errors[0], out
    assert not log.exists() or read_log(log).n_ticks == 0


def test_a_logger_killed_mid_run_is_said_at_once_and_loses_nothing_it_wrote(tmp_path: Path) -> None:
    """SIGKILL to the logger process alone while the run balances: the run says so at once and balances on; every
    chunk written before the kill stays readable (ours and the independent JavaScript reader agree), up to the
    flush period before it; the summary counts what the file holds and the run exits 3 (incomplete log)."""
    log = tmp_path / "run.mcap"
    daemon = DaemonProcess(["--mock", "--no-tui", "--duration", "60", "--log", str(log),
                            "--summary-json", str(tmp_path / "summary.json")])
    try:
        daemon.wait_for_line("→ balancing")
        waited_s = -daemon.run_queue_wait_s()
        time.sleep(2.0)
        logger = _logger_pid(daemon, starting=False)
        assert logger is not None
        waited_s += daemon.run_queue_wait_s()  # the time a loaded machine kept the run and its logger from a CPU
        t_kill = time.time_ns()
        os.kill(logger, signal.SIGKILL)
        line = daemon.wait_for_line("logger process died", timeout=30)
        assert daemon.proc.poll() is None, "the run went on"
        time.sleep(1.0)
        daemon.kill_group(signal.SIGINT)
        rc = daemon.wait()
    finally:
        daemon.kill_group(signal.SIGKILL)
    out = daemon.stderr + daemon.stdout
    assert traceback_free(out), out
    assert "SIGKILL" in line and str(log) in line
    assert rc == 3, out
    data = read_log(log)
    assert data.recovered and data.n_ticks > 0
    assert data.tick_log_time[-1] > t_kill - (1.6 + waited_s) * 1e9, (
        f"more than the flush period before the kill is missing ({waited_s:.2f} s of run-queue wait)")
    assert independent_mcap_counts(log)["tick_records"] == data.n_ticks
    summary = read_summary(tmp_path)
    assert summary["log_ticks"] == data.n_ticks < summary["ticks"]


def test_a_logger_killed_during_start_up_is_one_line_at_once(tmp_path: Path) -> None:
    """The logger dies while it starts (its imports take seconds): one line naming it, exit 2, well before the
    60 s start-up timeout, no device streaming."""
    daemon = DaemonProcess(["--mock", "--no-tui", "--duration", "5", "--log", str(tmp_path / "run.mcap")],
                           env=HELPER_ALWAYS)
    try:
        logger = _starting_logger(daemon)
        assert logger is not None, daemon.stderr
        os.kill(logger, signal.SIGKILL)
        t_kill = time.monotonic()
        rc = daemon.wait(timeout=TIMEOUT_S)
        took = time.monotonic() - t_kill
    finally:
        daemon.kill_group(signal.SIGKILL)
    out = _refused_in_start_up(daemon, rc, "logger process died during start-up")
    assert took < 30, (took, out)


def test_the_controller_design_helper_killed_during_start_up_is_one_line(tmp_path: Path) -> None:
    """The gains and observer matrices are made in a helper process before the first tick (scipy stays out of the
    real-time process): its death is one line naming it, exit 2, no device streaming, not a hang."""
    daemon = DaemonProcess(["--mock", "--no-tui", "--duration", "5", "--log", str(tmp_path / "run.mcap")],
                           env=HELPER_ALWAYS)
    try:
        _starting_logger(daemon)
        os.kill(_spawned(daemon)[0], signal.SIGKILL)
        rc = daemon.wait(timeout=TIMEOUT_S)
    finally:
        daemon.kill_group(signal.SIGKILL)
    _refused_in_start_up(daemon, rc, "controller design process died")
