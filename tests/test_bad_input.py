"""Issue 10, item 7: every bad input gets one line naming the problem, exit code 2, no traceback.

The matrix runs each command's ``main(argv)`` in-process (the same code the console scripts run; an
escaping exception fails the test with its traceback) and a few cases through the real console
scripts. Permission denied is checked as an unprivileged user: the suite may run as root, for whom
chmod 000 denies nothing, so a helper process imports the CLI as root, drops to uid/gid 65534 and
runs those cases (tests/test_reliability_harness.py ``asuser``).
"""

from __future__ import annotations

import io
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

import numpy as np
import pytest
from test_reliability_harness import FURUTA_RT, ROOT

from furuta_rt.cli import main as furuta_main
from furuta_rt.config import load_rig
from furuta_rt.io.csv import write_csv
from furuta_rt.io.mcap_log import write_recording_mcap
from furuta_rt.recording import Recording
from hil_mock.cli import main as mock_main
from hil_mock.ptyport import open_raw_pty

PNG = bytes.fromhex("89504e470d0a1a0a0000000d4948445200000001000000010806000000") + b"\x00" * 40
MCAP_MAGIC = b"\x89MCAP0\r\n"


def _thesis_toml() -> str:
    return (ROOT / "furuta_rt" / "rigs" / "thesis.toml").read_text()


def _recording(n: int = 400) -> Recording:
    t = np.arange(n) / 500.0
    theta = 0.01 * np.sin(2 * np.pi * 1.3 * t)
    phi = 0.1 * np.sin(2 * np.pi * 0.4 * t)
    u = -0.2 * np.sin(2 * np.pi * 1.3 * t)
    return Recording(t=t, theta=theta, phi=phi, u=u, theta_dot=np.gradient(theta, t))


@pytest.fixture(scope="module")
def files() -> Iterator[dict[str, Path]]:
    """Good and bad inputs in a world-readable directory (the unprivileged helper reads it too)."""
    d = Path(tempfile.mkdtemp(prefix="furuta-bad-input-"))
    d.chmod(0o755)
    thesis = _thesis_toml()
    f: dict[str, Path] = {}

    def put(name: str, data: str | bytes) -> Path:
        p = d / name
        p.write_bytes(data.encode() if isinstance(data, str) else data)
        p.chmod(0o644)
        f[name] = p
        return p

    put("bad_syntax.toml", 'name = "x"\n[plant\nl = 0.4\n')
    put("unknown_key.toml", thesis.replace("[plant]\n", "[plant]\nmasss = 0.02\n", 1))
    put("negative_mass.toml", thesis.replace("m = 0.02 ", "m = -0.02 ", 1))
    put("wrong_type.toml", re.sub(r"(?m)^l = 0\.413 ", 'l = "long" ', thesis, count=1))
    put("png.toml", PNG)
    put("empty.toml", "")
    (d / "dir.toml").mkdir()
    f["dir.toml"] = d / "dir.toml"
    f["missing.toml"] = d / "missing.toml"
    rec = _recording()
    write_csv(rec, put("good.csv", ""))
    write_recording_mcap(rec, d / "good.mcap", load_rig("thesis"))
    f["good.mcap"] = d / "good.mcap"
    (d / "good.mcap").chmod(0o644)
    good_mcap = (d / "good.mcap").read_bytes()
    put("empty.mcap", b"")
    put("random.mcap", np.random.default_rng(7).bytes(4096))
    put("png.mcap", PNG)
    put("truncated_header.mcap", MCAP_MAGIC[:5])
    put("magic_only.mcap", MCAP_MAGIC)
    put("magic_garbage.mcap", MCAP_MAGIC + np.random.default_rng(8).bytes(300))
    put("csv.mcap", (d / "good.csv").read_text())
    put("cut_in_header.mcap", good_mcap[:20])
    (d / "dir.mcap").mkdir()
    f["dir.mcap"] = d / "dir.mcap"
    f["missing.mcap"] = d / "missing.mcap"
    good_csv = (d / "good.csv").read_text().splitlines()
    put("missing_columns.csv", "t,theta,u\n0,0,0\n0.002,0,0\n0.004,0,0\n")
    put("non_numeric.csv", "\n".join([good_csv[0], good_csv[1], good_csv[2].replace(good_csv[2].split(",")[1], "abc", 1),
                                      *good_csv[3:10]]) + "\n")
    put("empty.csv", "")
    put("header_only.csv", good_csv[0] + "\n")
    put("png.csv", PNG)
    put("random.csv", np.random.default_rng(9).bytes(2000))
    f["missing.csv"] = d / "missing.csv"
    (d / "dir.csv").mkdir()
    f["dir.csv"] = d / "dir.csv"
    put("regular_file_port", b"")
    # mock configs
    put("mock_bad_syntax.toml", "rig = \n")
    put("mock_unknown_key.toml", 'rig = "thesis"\n[device]\nrate_hzz = 500\n')
    put("mock_negative.toml", 'rig = "thesis"\n[device]\nrate_hz = -5\n')
    put("mock_bad_fault.toml", 'rig = "thesis"\n[faults]\nschedule = ["explode@1"]\n')
    put("mock_bad_prob.toml", 'rig = "thesis"\n[faults]\ncorrupt_rate = 1.5\n')
    yield f
    shutil.rmtree(d, ignore_errors=True)


def _call(fn, argv: list[str]) -> tuple[int, str, str]:
    err, out = io.StringIO(), io.StringIO()
    with redirect_stderr(err), redirect_stdout(out):
        try:
            rc = fn(argv)
        except SystemExit as exc:  # argparse usage errors
            rc = exc.code if isinstance(exc.code, int) else 1
    return rc, out.getvalue(), err.getvalue()


def _check(rc: int, stderr: str, *mentions: str | tuple[str, ...]) -> None:
    """Exit 2, exactly one line on stderr, no traceback; the line contains each of ``mentions`` (a tuple:
    any one of its alternatives)."""
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    assert "Traceback" not in stderr, stderr
    assert rc == 2, f"exit {rc}, stderr: {stderr!r}"
    assert len(lines) == 1, f"expected exactly one line on stderr, got {len(lines)}: {stderr!r}"
    low = lines[0].lower()
    for m in mentions:
        alternatives = m if isinstance(m, tuple) else (m,)
        assert any(a.lower() in low for a in alternatives), f"the message does not name {m!r}: {lines[0]!r}"


# ------------------------------------------------------------------ configuration (rig TOML)
BAD_RIGS = {
    "bad_syntax.toml": ("bad_syntax.toml", "toml"),
    "unknown_key.toml": ("masss",),
    "negative_mass.toml": ("m",),
    "wrong_type.toml": ("l",),
    "png.toml": ("png.toml",),
    "empty.toml": ("empty.toml",),
    "dir.toml": ("dir.toml",),
    "missing.toml": ("missing.toml",),
}


def _rig_commands(f: dict[str, Path], cfg: str) -> dict[str, list[str]]:
    return {
        "design": ["design", "--config", cfg],
        "run": ["run", "--port", "/dev/null", "--duration", "1", "--config", cfg],
        "replay": ["replay", str(f["good.mcap"]), "--config", cfg],
        "convert": ["convert", str(f["good.csv"]), "-o", str(f["good.csv"].parent / "out.mcap"), "--config", cfg],
        "diagnose": ["diagnose", str(f["good.csv"]), "--config", cfg, "--no-closed-loop"],
        "analyze": ["analyze", "limit-cycle", "--config", cfg],
    }


@pytest.mark.parametrize("bad", list(BAD_RIGS))
@pytest.mark.parametrize("command", ["design", "run", "replay", "convert", "diagnose", "analyze", "hil-mock"])
def test_bad_rig_config(files: dict[str, Path], command: str, bad: str) -> None:
    cfg = str(files[bad])
    if command == "hil-mock":
        rc, _, err = _call(mock_main, ["--pty", "--rig", cfg, "--duration", "0.1"])
    else:
        rc, _, err = _call(furuta_main, _rig_commands(files, cfg)[command])
    _check(rc, err, *BAD_RIGS[bad])


# ------------------------------------------------------------------ log files (MCAP)
BAD_LOGS = ["empty.mcap", "random.mcap", "png.mcap", "truncated_header.mcap", "magic_only.mcap", "magic_garbage.mcap",
            "csv.mcap", "cut_in_header.mcap", "dir.mcap", "missing.mcap"]


LOG_CASES = [(c, b) for c in ("replay", "repair", "convert", "diagnose") for b in BAD_LOGS
             if not (b == "csv.mcap" and c in ("convert", "diagnose"))]  # those read a CSV by content, any name


@pytest.mark.parametrize(("command", "bad"), LOG_CASES)
def test_bad_log_file(files: dict[str, Path], command: str, bad: str) -> None:
    """A file that is not MCAP, or an MCAP file with nothing recoverable in it (cut inside its header,
    magic and garbage): an error, not an empty output written with exit 0."""
    path = str(files[bad])
    out_dir = files["good.csv"].parent
    argv = {
        "replay": ["replay", path],
        "repair": ["repair", path, "-o", str(out_dir / f"repaired_{bad}")],
        "convert": ["convert", path, "-o", str(out_dir / f"converted_{bad}.csv")],
        "diagnose": ["diagnose", path, "--no-closed-loop"],
    }[command]
    rc, _, err = _call(furuta_main, argv)
    _check(rc, err, (bad, "0 samples", "no complete", "no ticks", "nothing"))


# ------------------------------------------------------------------ recordings (CSV)
BAD_CSVS = {
    "missing_columns.csv": ("missing_columns.csv", "phi"),
    "non_numeric.csv": ("non_numeric.csv", "abc"),
    "empty.csv": ("empty.csv",),
    "header_only.csv": ("header_only.csv",),
    "png.csv": ("png.csv",),
    "random.csv": ("random.csv",),
    "missing.csv": ("missing.csv",),
    "dir.csv": ("dir.csv",),
}


@pytest.mark.parametrize("bad", list(BAD_CSVS))
@pytest.mark.parametrize("command", ["convert", "diagnose"])
def test_bad_csv(files: dict[str, Path], command: str, bad: str) -> None:
    path = str(files[bad])
    argv = {
        "convert": ["convert", path, "-o", str(files["good.csv"].parent / f"from_{bad}.mcap")],
        "diagnose": ["diagnose", path, "--no-closed-loop"],
    }[command]
    rc, _, err = _call(furuta_main, argv)
    _check(rc, err, *BAD_CSVS[bad])


# ------------------------------------------------------------------ serial devices and the log path of `run`
def test_missing_serial_device() -> None:
    rc, _, err = _call(furuta_main, ["run", "--port", "/dev/ttyNOPE7", "--duration", "1", "--no-rt"])
    _check(rc, err, "/dev/ttyNOPE7", "--mock")


@pytest.mark.parametrize("port", ["dir", "regular_file_port"])
def test_serial_port_that_is_not_a_tty(files: dict[str, Path], port: str) -> None:
    path = str(files["good.csv"].parent) if port == "dir" else str(files[port])
    rc, _, err = _call(furuta_main, ["run", "--port", path, "--duration", "1", "--no-rt"])
    _check(rc, err, path)


def test_busy_serial_device() -> None:
    """Another program holds the port (pyserial exclusive lock, as the daemon itself takes it)."""
    import serial

    fd, port = open_raw_pty()
    holder = serial.Serial(port, exclusive=True)
    try:
        rc, _, err = _call(furuta_main, ["run", "--port", port, "--duration", "1", "--no-rt"])
    finally:
        holder.close()
        os.close(fd)
    _check(rc, err, port, "busy")


@pytest.mark.parametrize("where", ["directory", "missing_parent"])
def test_unwritable_log_path(files: dict[str, Path], where: str) -> None:
    d = files["good.csv"].parent
    log = str(d / "dir.mcap") if where == "directory" else str(d / "no" / "such" / "dir" / "run.mcap")
    rc, _, err = _call(furuta_main, ["run", "--port", "/dev/ttyNOPE7", "--duration", "1", "--log", log, "--no-rt"])
    _check(rc, err, log)


# ------------------------------------------------------------------ hil-mock's own configuration
BAD_MOCK = {
    "mock_bad_syntax.toml": ("mock_bad_syntax.toml",),
    "mock_unknown_key.toml": ("rate_hzz",),
    "mock_negative.toml": ("rate_hz",),
    "mock_bad_fault.toml": ("explode",),
    "mock_bad_prob.toml": ("corrupt_rate",),
    "missing.toml": ("missing.toml",),
    "dir.toml": ("dir.toml",),
    "png.toml": ("png.toml",),
}


@pytest.mark.parametrize("bad", list(BAD_MOCK))
def test_bad_mock_config(files: dict[str, Path], bad: str) -> None:
    rc, _, err = _call(mock_main, ["--pty", "--mock-config", str(files[bad]), "--duration", "0.1"])
    _check(rc, err, *BAD_MOCK[bad])


@pytest.mark.parametrize("argv", [["--fault", "stall@soon"], ["--corrupt-rate", "2"], ["--rate", "0"],
                                  ["--effect", "arm_coulomb.Fc=abc"], ["--effect", "warp_drive.x=1"], ["--cpu", "4096"]])
def test_bad_mock_options(argv: list[str]) -> None:
    rc, _, err = _call(mock_main, ["--pty", "--duration", "0.1", *argv])
    _check(rc, err)


# ------------------------------------------------------------------ through the real console scripts
@pytest.mark.parametrize("argv", [
    ["replay", "{png.mcap}"],
    ["run", "--port", "/dev/ttyNOPE7", "--duration", "1"],
])
def test_console_script_one_line_exit_2(files: dict[str, Path], argv: list[str]) -> None:
    names = {k: str(v) for k, v in files.items()} | {"dir": str(files["good.csv"].parent)}
    for key, value in names.items():
        argv = [a.replace("{" + key + "}", value) for a in argv]
    proc = subprocess.run([*FURUTA_RT, *argv], capture_output=True, text=True, timeout=120, cwd=ROOT)
    _check(proc.returncode, proc.stderr)
    assert proc.stderr.startswith(f"furuta-rt {argv[0]}: error: ")


def test_hil_mock_console_script_one_line_exit_2(files: dict[str, Path]) -> None:
    proc = subprocess.run([sys.executable, "-m", "hil_mock", "--mock-config", str(files["mock_unknown_key.toml"])],
                          capture_output=True, text=True, timeout=120, cwd=ROOT)
    _check(proc.returncode, proc.stderr, "rate_hzz")


# ------------------------------------------------------------------ permission denied (as a non-root user)
def test_permission_denied_as_unprivileged_user(files: dict[str, Path]) -> None:
    d = files["good.csv"].parent
    secret = {}
    for name in ("good.mcap", "good.csv"):
        p = d / f"secret_{name}"
        shutil.copy(files[name], p)
        p.chmod(0o000)
        secret[name] = str(p)
    rig = d / "secret_rig.toml"
    rig.write_text(_thesis_toml())
    rig.chmod(0o000)
    fd, port = open_raw_pty()  # a pty slave is root:tty 0620: others may not open it
    os.chmod(port, 0o600)
    readonly = d / "readonly"
    readonly.mkdir(exist_ok=True)
    readonly.chmod(0o755)
    cases = {
        "design": ["design", "--config", str(rig)],
        "run_config": ["run", "--port", port, "--config", str(rig), "--duration", "1"],
        "run_port": ["run", "--port", port, "--duration", "1", "--no-rt"],
        "run_log": ["run", "--port", port, "--duration", "1", "--no-rt", "--log", str(readonly / "run.mcap")],
        "replay": ["replay", secret["good.mcap"]],
        "repair": ["repair", secret["good.mcap"], "-o", str(readonly / "fixed.mcap")],
        "repair_out": ["repair", str(files["good.mcap"]), "--force", "-o", str(readonly / "fixed.mcap")],
        "convert_in": ["convert", secret["good.csv"], "-o", str(readonly / "x.mcap")],
        "convert_out": ["convert", str(files["good.csv"]), "-o", str(readonly / "x.mcap")],
        "diagnose": ["diagnose", secret["good.csv"], "--no-closed-loop"],
    }
    try:
        proc = subprocess.run(
            [sys.executable, str(ROOT / "tests" / "test_reliability_harness.py"), "asuser", json.dumps(cases)],
            capture_output=True, text=True, timeout=300, cwd=ROOT,
        )
    finally:
        os.close(fd)
    assert proc.returncode == 0, proc.stderr
    results = json.loads(proc.stdout.strip().splitlines()[-1])
    assert results.pop("__uid__") == 65534
    problems = []
    for name, (rc, err) in results.items():
        try:
            _check(rc, err)
            assert "permission" in err.lower(), f"does not say 'permission denied': {err!r}"
        except AssertionError as exc:
            problems.append(f"{name}: {exc}")
    assert not problems, "\n".join(problems)


# ------------------------------------------------------------------ a port with no (or a vanishing) device behind it
def _run_on_pty(on_hello_close: bool) -> subprocess.CompletedProcess[str]:
    """``furuta-rt run --port`` on a raw pty served by nobody; with ``on_hello_close`` the "device" closes
    its side as soon as the host's first bytes (the HELLO) arrive."""
    import select

    fd, port = open_raw_pty()
    proc = subprocess.Popen([*FURUTA_RT, "run", "--port", port, "--duration", "1", "--no-rt", "--no-tui"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        if on_hello_close:
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline:
                if select.select([fd], [], [], 0.1)[0]:
                    try:
                        if os.read(fd, 4096):
                            break
                    except OSError:  # EIO until the host opens the port
                        time.sleep(0.01)
            os.close(fd)
            fd = -1
        out, err = proc.communicate(timeout=120)
    finally:
        if fd >= 0:
            os.close(fd)
        if proc.poll() is None:
            proc.kill()
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, err)


def test_port_with_no_device_answering() -> None:
    proc = _run_on_pty(on_hello_close=False)
    _check(proc.returncode, proc.stderr, "HELLO_ACK")


def test_device_vanishing_during_the_handshake() -> None:
    """The port closes while the host waits for HELLO_ACK (device unplugged, mock crashed): a clear line,
    non-zero exit, no traceback."""
    proc = _run_on_pty(on_hello_close=True)
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert "Traceback" not in proc.stderr, proc.stderr
    assert proc.returncode in (1, 2), proc.stderr
    assert len(lines) == 1 and "error" in lines[0], proc.stderr
