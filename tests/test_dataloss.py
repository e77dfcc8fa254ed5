"""Issue 15 (items 4-7, 9-12): nothing of the user's is lost, no run that failed looks like success, unit
mistakes are named, and the CLI works from any clone location. Every case runs the real console script
(``furuta-rt``, ``scripts/demo``) as a subprocess.
"""

from __future__ import annotations

import json
import os
import pkgutil
import re
import secrets
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest
import test_reliability_harness as harness
from test_reliability_harness import FURUTA_RT, LOCKSTEP, ROOT, UNPRIVILEGED

from furuta_rt import cli
from furuta_rt.config import SHIPPED_RIGS, implausible, load_rig
from furuta_rt.io.csv import write_csv
from furuta_rt.io.mcap_log import write_recording_mcap
from furuta_rt.io.mcap_read import read_log
from furuta_rt.recording import Recording


def _cli(cwd: Path, *args: str, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*FURUTA_RT, *args], cwd=cwd, capture_output=True, text=True, timeout=timeout)


def _one_line_error(proc: subprocess.CompletedProcess[str], *mentions: str) -> str:
    """Exit 2, one stderr line without a traceback, naming each of ``mentions``; returns the line."""
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert "Traceback" not in proc.stderr, proc.stderr
    assert proc.returncode == 2, f"exit {proc.returncode}: {proc.stderr}{proc.stdout[-2000:]}"
    assert len(lines) == 1, proc.stderr
    for m in mentions:
        assert m.lower() in lines[0].lower(), f"{m!r} not in {lines[0]!r}"
    return lines[0]


def _log(path: Path, seconds: float = 4.0) -> Path:
    """A closed log of ``seconds`` at 500 Hz (7 chunks for 4 s)."""
    t = np.arange(round(seconds * 500)) / 500.0
    rec = Recording(t=t, theta=0.01 * np.sin(3 * t), phi=0.1 * np.sin(t), u=0.1 * np.cos(3 * t),
                    theta_dot=0.03 * np.cos(3 * t))
    write_recording_mcap(rec, path, load_rig("thesis"))
    return path


def _files(d: Path) -> list[str]:
    return sorted(p.name for p in d.iterdir())


# ------------------------------------------------------------------ item 4: repair never loses its input
@pytest.mark.parametrize("onto", ["itself", "in_place"])
def test_repair_with_nothing_recoverable_leaves_the_input_alone(tmp_path: Path, onto: str) -> None:
    good = _log(tmp_path / "good.mcap").read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(good[:3000])  # header, metadata, attachment: cut before the first chunk ends
    proc = _cli(tmp_path, "repair", "cut.mcap", *(["-o", "cut.mcap"] if onto == "itself" else []))
    _one_line_error(proc, "cut.mcap", "no complete chunk")
    assert cut.read_bytes() == good[:3000]
    assert _files(tmp_path) == ["cut.mcap", "good.mcap"]  # no .bak, no temporary file left


def test_repair_force_onto_itself_rewrites_it_and_keeps_the_original(tmp_path: Path) -> None:
    log = _log(tmp_path / "run.mcap")
    before = log.read_bytes()
    proc = _cli(tmp_path, "repair", "run.mcap", "--force", "-o", "run.mcap")
    assert proc.returncode == 0, proc.stderr
    assert "kept as run.mcap.bak" in proc.stdout and "dropped" not in proc.stdout, proc.stdout
    assert (tmp_path / "run.mcap.bak").read_bytes() == before
    fixed = read_log(log)
    assert fixed.n_ticks == 2000 and not fixed.recovered
    assert _files(tmp_path) == ["run.mcap", "run.mcap.bak"]


def test_repair_replaces_another_existing_output_only_with_force(tmp_path: Path) -> None:
    good = _log(tmp_path / "good.mcap").read_bytes()
    torn = tmp_path / "torn.mcap"
    torn.write_bytes(good[:-1000])  # every chunk, the summary cut
    other = tmp_path / "other.mcap"
    other.write_bytes(b"the user's own file")
    _one_line_error(_cli(tmp_path, "repair", "torn.mcap", "-o", "other.mcap"), "other.mcap", "exists", "--force")
    assert other.read_bytes() == b"the user's own file" and torn.read_bytes() == good[:-1000]
    proc = _cli(tmp_path, "repair", "torn.mcap", "-o", "other.mcap", "--force")
    assert proc.returncode == 0, proc.stderr
    assert read_log(other).n_ticks == 2000 and torn.read_bytes() == good[:-1000]
    assert _files(tmp_path) == ["good.mcap", "other.mcap", "torn.mcap"]


# ------------------------------------------------------------------ item 5: outputs that exist are not replaced unasked
def test_run_log_refuses_an_existing_recording(tmp_path: Path) -> None:
    before = _log(tmp_path / "old.mcap").read_bytes()
    proc = _cli(tmp_path, "run", "--mock", "--duration", "1", "--no-rt", "--no-tui", "--log", "old.mcap")
    _one_line_error(proc, "old.mcap", "already exists", "--force")
    assert (tmp_path / "old.mcap").read_bytes() == before


def test_run_log_force_replaces_the_recording_only_once_the_device_answers(tmp_path: Path) -> None:
    old = _log(tmp_path / "old.mcap")
    before = old.read_bytes()
    summary = tmp_path / "old.json"
    summary.write_text('{"an earlier summary": true}\n')
    # the device is missing: the run never starts, the old recording and summary stay as they were
    proc = _cli(tmp_path, "run", "--port", str(tmp_path / "ttyNOPE"), "--duration", "1", "--no-rt", "--no-tui",
                "--log", "old.mcap", "--summary-json", "old.json", "--force")
    _one_line_error(proc, "ttyNOPE", "does not exist")
    assert old.read_bytes() == before and summary.read_text() == '{"an earlier summary": true}\n'
    # a run that balances replaces both
    proc = _cli(tmp_path, "run", "--mock", "--duration", "1", "--no-rt", "--no-tui", "--log", "old.mcap",
                "--summary-json", "old.json", "--force", LOCKSTEP)
    assert proc.returncode == 0, proc.stderr
    new = read_log(old)
    assert not new.converted and new.n_ticks >= 400
    assert json.loads(summary.read_text())["ticks"] >= 400
    assert _files(tmp_path) == ["old.json", "old.mcap"]


def test_run_log_must_be_an_mcap_name(tmp_path: Path) -> None:
    proc = _cli(tmp_path, "run", "--mock", "--duration", "1", "--no-rt", "--no-tui", "--log", "x.csv")
    _one_line_error(proc, "x.csv", ".mcap", "convert")
    assert _files(tmp_path) == []


def test_convert_refuses_an_existing_output_and_replaces_it_with_force(tmp_path: Path) -> None:
    _log(tmp_path / "run.mcap")
    out = tmp_path / "out.csv"
    out.write_text("t,theta,phi,u\n0,0,0,0\n")
    _one_line_error(_cli(tmp_path, "convert", "run.mcap", "-o", "out.csv"), "out.csv", "already exists", "--force")
    assert out.read_text() == "t,theta,phi,u\n0,0,0,0\n"
    proc = _cli(tmp_path, "convert", "run.mcap", "-o", "out.csv", "--force")
    assert proc.returncode == 0, proc.stderr
    assert len(out.read_text().splitlines()) == 2001
    assert _files(tmp_path) == ["out.csv", "run.mcap"]


# ------------------------------------------------------------------ item 7: a run that never balanced is not a success
def test_a_run_that_never_balanced_exits_non_zero(tmp_path: Path) -> None:
    """The mock starts at θ = 0.4 rad, outside the 0.1 rad arming window: the pendulum falls, never arms."""
    proc = _cli(tmp_path, "run", "--mock", "--mock-initial-theta", "0.4", "--duration", "1", "--no-rt", "--no-tui",
                "--summary-json", "s.json", LOCKSTEP)
    s = json.loads((tmp_path / "s.json").read_text())
    assert s["end"] == "duration" and s["balancing_ticks"] == 0 and s["ticks"] >= 400
    assert proc.returncode == 4, proc.stderr
    errors = [ln for ln in proc.stderr.splitlines() if "error" in ln]
    assert len(errors) == 1 and "never balanced" in errors[0] and "0.1 rad" in errors[0], proc.stderr


# ------------------------------------------------------------------ item 9: implausible input, one line naming the key
def _rig_with(tmp: Path, key: str, value: str) -> str:
    text = (ROOT / "furuta_rt" / "rigs" / "thesis.toml").read_text()
    text, n = re.subn(rf"(?m)^{key} = \S+", f"{key} = {value}", text, count=1)
    assert n == 1
    path = tmp / f"rig_{key}.toml"
    path.write_text(text)
    return str(path)


@pytest.mark.parametrize("case", ["gains_nan", "length_in_cm", "mass_in_g", "gravity_in_cm", "toml_inf",
                                  "tui_and_no_tui", "port_not_serial"])
def test_implausible_input_is_named_in_one_line(tmp_path: Path, case: str) -> None:
    run = ["run", "--duration", "1", "--no-rt"]
    argv, mentions = {
        "gains_nan": ([*run, "--mock", "--no-tui", "--gains", "nan,1,1,1"], ("--gains", "l1 = nan", "finite")),
        "length_in_cm": (["design", "--config", _rig_with(tmp_path, "l", "41.3")], ("plant.l", "in cm?", "0.413 m")),
        "mass_in_g": (["design", "--config", _rig_with(tmp_path, "m", "20")], ("plant.m", "in g?", "0.02 kg")),
        "gravity_in_cm": (["design", "--config", _rig_with(tmp_path, "g", "981")], ("plant.g", "cm/s²", "9.81")),
        "toml_inf": (["design", "--config", _rig_with(tmp_path, "theta_limit", "inf")], ("safety.theta_limit", "finite")),
        "tui_and_no_tui": ([*run, "--mock", "--tui", "--no-tui"], ("--tui", "--no-tui")),
        "port_not_serial": ([*run, "--no-tui", "--port", "/dev/null"], ("/dev/null", "not a serial port")),
    }[case]
    _one_line_error(_cli(tmp_path, *argv), *mentions)


def test_shipped_rigs_are_plausible() -> None:
    for name in SHIPPED_RIGS:
        assert implausible(load_rig(name)) == []


@pytest.mark.parametrize(("key", "value", "mentions"), [
    ("l", "41.3", ("plant.l", "in cm?", "0.413 m")),
    ("theta_limit", "28.6", ("safety.theta_limit", "in degrees?", "0.4992 rad")),
])
def test_diagnose_refuses_a_config_in_a_wrong_unit(tmp_path: Path, key: str, value: str, mentions: tuple[str, ...]) -> None:
    """A length in cm or a limit in degrees is a unit mistake, not physics a recording can show: diagnose refuses it as
    run and design do, one line naming the key and the likely unit, and writes nothing."""
    t = np.arange(1500) / 500.0
    write_csv(Recording(t=t, theta=0.01 * np.sin(3 * t), phi=0.1 * np.sin(t), u=0.1 * np.cos(3 * t)), tmp_path / "r.csv")
    proc = _cli(tmp_path, "diagnose", "r.csv", "--config", _rig_with(tmp_path, key, value), "--no-closed-loop",
                "--json", "out.json")
    _one_line_error(proc, *mentions)
    assert not (tmp_path / "out.json").exists()


# ------------------------------------------------------------------ item 10: scripts/demo resolves paths from the caller's folder
def test_demo_writes_a_relative_log_in_the_callers_folder(tmp_path: Path) -> None:
    name = f"rel_{secrets.token_hex(4)}.mcap"
    env = {**os.environ, "VENV_EXTRAS": "test"}  # the venv the suite runs in: no install
    try:
        proc = subprocess.run([str(ROOT / "scripts" / "demo"), "--duration", "1", "--no-rt", "--no-tui", "--log", name],
                              cwd=tmp_path, capture_output=True, text=True, timeout=180, env=env)
        in_root = (ROOT / name).exists()
    finally:
        (ROOT / name).unlink(missing_ok=True)
    assert not in_root, "the demo wrote the log into the repository root"
    assert proc.returncode == 0, proc.stderr  # README's quick start: the simulated pendulum balances
    assert f"log: {name}" in proc.stdout
    assert read_log(tmp_path / name).n_ticks >= 400


# ------------------------------------------------------------------ item 11: the CLI does not depend on listing its package
def test_every_command_module_is_listed() -> None:
    modules = sorted(m.name for m in pkgutil.iter_modules(cli.__path__) if not m.name.startswith("_"))
    assert sorted(cli.COMMANDS) == modules


_UNLISTABLE = """
import contextlib, importlib, io, json, os, pkgutil, sys
sys.path.insert(0, sys.argv[1])
import furuta_rt
from furuta_rt import cli
assert furuta_rt.__file__.startswith(sys.argv[1]), furuta_rt.__file__
for info in pkgutil.walk_packages(furuta_rt.__path__, "furuta_rt."):
    importlib.import_module(info.name)  # as root: every module is loaded before the privileges go
os.setgroups([]); os.setgid(int(sys.argv[2])); os.setuid(int(sys.argv[2]))
err = io.StringIO()
with contextlib.redirect_stderr(err):
    try:
        rc = cli.main(["repair", "/nonexistent/x.mcap"])
    except SystemExit as exc:
        rc = exc.code
print(json.dumps([os.getuid(), rc, err.getvalue()]))
"""


def test_cli_keeps_its_commands_where_its_package_cannot_be_listed() -> None:
    """A clone in a private directory (``mktemp -d``, /root) run by another uid: the package directory
    cannot be listed; every command must still be there."""
    private = Path(tempfile.mkdtemp(prefix="furuta-private-"))
    try:
        assert private.stat().st_mode & 0o077 == 0
        shutil.copytree(ROOT / "furuta_rt", private / "furuta_rt", ignore=shutil.ignore_patterns("__pycache__"))
        proc = subprocess.run([sys.executable, "-c", _UNLISTABLE, str(private), str(UNPRIVILEGED)],
                              capture_output=True, text=True, timeout=300, cwd="/")
    finally:
        shutil.rmtree(private, ignore_errors=True)
    assert proc.returncode == 0, proc.stderr
    uid, rc, err = json.loads(proc.stdout.strip().splitlines()[-1])
    assert uid == UNPRIVILEGED
    assert rc == 2 and "invalid choice" not in err and "/nonexistent/x.mcap does not exist" in err, err


# ------------------------------------------------------------------ item 12: the independent reader is independent or fails
def test_independent_reader_never_falls_back_to_a_python_reader(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    log = _log(tmp_path / "run.mcap", seconds=1.0)
    assert harness.independent_mcap_counts(log)["reader"] == harness.INDEPENDENT_READER
    monkeypatch.setattr(harness, "ensure_node_mcap", lambda: None)  # node or @mcap/core missing
    with pytest.raises(RuntimeError, match="unavailable"):
        harness.independent_mcap_counts(log)
