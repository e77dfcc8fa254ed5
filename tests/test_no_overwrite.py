"""A user's file is never overwritten unless asked: every command that writes a file the user named refuses an
existing one (exit 2, one line naming it and --force, no traceback) before doing any work, leaves it byte for byte
as it was, and replaces it with --force only once the new content is complete. The commands run as real
subprocesses of the console script; the shared helper (furuta_rt.io.output) is also driven directly for what a
subprocess cannot time: a file that appears while the command works, a writer that fails half-way.
"""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
from test_reliability_harness import FURUTA_RT

from furuta_rt.cli import main
from furuta_rt.config import load_rig
from furuta_rt.diagnose.report.render import OUTPUTS
from furuta_rt.errors import UserError
from furuta_rt.io.csv import write_csv
from furuta_rt.io.mcap_log import write_recording_mcap
from furuta_rt.io.output import claim_directory, claim_outputs, directory_when_done, replace_when_done
from furuta_rt.recording import Recording

MINE = b"the user's own file \x00\x01 (not ours to replace)\n"
PNG = b"\x89PNG\r\n\x1a\n"
QUICK_DIAGNOSE = ("--no-closed-loop", "--skip-convention-check")


def _recording(seconds: float) -> Recording:
    t = np.arange(round(seconds * 500)) / 500.0
    return Recording(t=t, theta=0.01 * np.sin(3 * t), phi=0.1 * np.sin(t), u=0.1 * np.cos(3 * t),
                     theta_dot=0.03 * np.cos(3 * t))


@pytest.fixture(scope="module")
def inputs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A 2 s log (1000 ticks) and a 3 s CSV: the smallest inputs every command accepts."""
    d = tmp_path_factory.mktemp("inputs")
    log, csv = d / "run.mcap", d / "r.csv"
    write_recording_mcap(_recording(2.0), log, load_rig("thesis"))
    write_csv(_recording(3.0), csv)
    return {"log": log, "csv": csv}


def _cli(cwd: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*FURUTA_RT, *args], cwd=cwd, capture_output=True, text=True, timeout=120)


def _refused(proc: subprocess.CompletedProcess[str], flag: str, name: str) -> None:
    """Exit 2, one stderr line without a traceback that names the option, the file and --force."""
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert "Traceback" not in proc.stderr, proc.stderr
    assert proc.returncode == 2, f"exit {proc.returncode}: {proc.stderr}{proc.stdout[-2000:]}"
    assert len(lines) == 1, proc.stderr
    assert f"{flag} {name} already exists" in lines[0] and "refusing to overwrite" in lines[0], lines[0]
    assert "pass --force" in lines[0], lines[0]


# Each case: the arguments ({log}, {csv}: the inputs), the option whose existing file is refused, that file, and
# another output of the same command that must not appear (the refusal comes before any work).
REFUSALS = {
    "convert_plot": (["convert", "{log}", "-o", "new.csv", "--plot", "old.png"], "--plot", "old.png", "new.csv"),
    "replay_csv": (["replay", "{log}", "--csv", "old.csv", "--plot", "new.png"], "--csv", "old.csv", "new.png"),
    "replay_plot": (["replay", "{log}", "--csv", "new.csv", "--plot", "old.png"], "--plot", "old.png", "new.csv"),
    "diagnose_json": (["diagnose", "{csv}", *QUICK_DIAGNOSE, "--json", "old.json", "--report", "new_dir"],
                      "--json", "old.json", "new_dir"),
    "analyze_plot": (["analyze", "limit-cycle", "--plot", "old.png", "--orbit"], "--plot", "old.png", None),
    "run_summary_json": (["run", "--mock", "--duration", "1", "--no-rt", "--no-tui", "--summary-json", "old.json",
                          "--log", "new.mcap"], "--summary-json", "old.json", "new.mcap"),
}


@pytest.mark.parametrize("case", list(REFUSALS))
def test_an_existing_output_is_refused_before_any_work(tmp_path: Path, inputs: dict[str, Path], case: str) -> None:
    argv, flag, name, other = REFUSALS[case]
    argv = [a.format(log=inputs["log"], csv=inputs["csv"]) for a in argv]
    (tmp_path / name).write_bytes(MINE)
    _refused(_cli(tmp_path, *argv), flag, name)
    assert (tmp_path / name).read_bytes() == MINE
    assert sorted(p.name for p in tmp_path.iterdir()) == [name]  # `other` not written, no temporary file left
    assert other is None or not (tmp_path / other).exists()


def test_with_force_each_output_is_replaced(tmp_path: Path, inputs: dict[str, Path]) -> None:
    for name in ("c.png", "r.csv", "r.png", "d.json", "a.png"):
        (tmp_path / name).write_bytes(MINE)
    proc = _cli(tmp_path, "convert", str(inputs["log"]), "-o", "c.csv", "--plot", "c.png", "--force")
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "c.png").read_bytes().startswith(PNG)
    proc = _cli(tmp_path, "replay", str(inputs["log"]), "--csv", "r.csv", "--plot", "r.png", "--force")
    assert proc.returncode == 0, proc.stderr
    rows = (tmp_path / "r.csv").read_text().splitlines()
    assert rows[0].startswith("t,theta,theta_dot,phi,u,u_logged") and len(rows) == 1001
    assert (tmp_path / "r.png").read_bytes().startswith(PNG)
    proc = _cli(tmp_path, "diagnose", str(inputs["csv"]), *QUICK_DIAGNOSE, "--json", "d.json", "--force")
    assert proc.returncode == 0, proc.stderr
    assert json.loads((tmp_path / "d.json").read_text())["equations"]
    proc = _cli(tmp_path, "analyze", "limit-cycle", "--plot", "a.png", "--force")
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "a.png").read_bytes().startswith(PNG)
    assert not [p.name for p in tmp_path.iterdir() if ".partial" in p.name]


def test_an_earlier_report_is_replaced_only_with_force(tmp_path: Path, inputs: dict[str, Path]) -> None:
    """--report DIR holding an earlier report: refused (every file of it kept) before the diagnosis; with --force the
    new report replaces it and a figure the new diagnosis does not draw is not left beside the new page."""
    out = tmp_path / "rep"
    assert main(["diagnose", str(inputs["csv"]), *QUICK_DIAGNOSE, "--report", str(out)]) == 0
    (out / "decay.png").write_bytes(PNG + b"a stale figure of an earlier diagnosis")
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    proc = _cli(tmp_path, "diagnose", str(inputs["csv"]), *QUICK_DIAGNOSE, "--report", "rep", "--json", "new.json")
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert proc.returncode == 2 and len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert "--report rep already holds" in lines[0] and "pass --force" in lines[0], lines[0]
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert not (tmp_path / "new.json").exists()
    proc = _cli(tmp_path, "diagnose", str(inputs["csv"]), *QUICK_DIAGNOSE, "--report", "rep", "--force")
    assert proc.returncode == 0, proc.stderr
    after = {p.name: p.read_bytes() for p in out.iterdir()}
    assert set(after) == set(before) - {"decay.png"}
    assert "furuta-rt diagnose" in after["report.html"].decode()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rep"]  # no temporary directory left


def test_a_report_directory_holding_a_users_file_of_the_same_name_is_refused_even_with_force(tmp_path: Path) -> None:
    (tmp_path / "summary.md").write_bytes(MINE)
    with pytest.raises(UserError, match=r"summary\.md"):
        claim_directory("--report", tmp_path, OUTPUTS, force=False)
    assert main(["diagnose", str(tmp_path / "none.csv"), "--report", str(tmp_path), "--force"]) == 2
    assert (tmp_path / "summary.md").read_bytes() == MINE


# ------------------------------------------------------------------ the helper itself
def test_the_same_file_named_twice_or_as_the_input_is_refused(tmp_path: Path, inputs: dict[str, Path],
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["replay", str(inputs["log"]), "--csv", str(tmp_path / "x"), "--plot", str(tmp_path / "x")]) == 2
    assert "--plot" in capsys.readouterr().err and not (tmp_path / "x").exists()
    assert main(["diagnose", str(inputs["csv"]), "--json", str(inputs["csv"]), "--force"]) == 2
    err = capsys.readouterr().err
    assert "is the input" in err and err.count("\n") == 1
    assert inputs["csv"].read_text().startswith("t,")


def test_a_file_that_appears_while_the_command_works_is_not_replaced(tmp_path: Path) -> None:
    target = tmp_path / "out.csv"
    claim_outputs([("--csv", target)], force=False)  # nothing there when the command starts
    with pytest.raises(UserError, match=r"--csv .*out\.csv already exists"), \
            replace_when_done(target, overwrite=False, flag="--csv") as tmp:
        tmp.write_text("the new content\n")
        target.write_bytes(MINE)  # another process creates it meanwhile
    assert target.read_bytes() == MINE
    assert [p.name for p in tmp_path.iterdir()] == ["out.csv"]
    with replace_when_done(target, overwrite=True, flag="--csv") as tmp:  # --force
        tmp.write_text("the new content\n")
    assert target.read_text() == "the new content\n"


def test_a_writer_that_fails_half_way_leaves_the_old_file_and_directory(tmp_path: Path) -> None:
    target = tmp_path / "out.png"
    target.write_bytes(MINE)
    with pytest.raises(RuntimeError), replace_when_done(target, overwrite=True, flag="--plot") as tmp:
        tmp.write_bytes(PNG)
        raise RuntimeError("the writer crashed")
    assert target.read_bytes() == MINE and [p.name for p in tmp_path.iterdir()] == ["out.png"]
    rep = tmp_path / "rep"
    rep.mkdir()
    (rep / "report.html").write_bytes(MINE)
    with pytest.raises(RuntimeError), directory_when_done(rep, OUTPUTS, overwrite=True, flag="--report") as tmp:
        (tmp / "report.html").write_text("half a page")
        raise RuntimeError("the diagnosis crashed")
    assert [p.name for p in rep.iterdir()] == ["report.html"] and (rep / "report.html").read_bytes() == MINE
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.png", "rep"]


def test_the_run_log_is_created_exclusively_unless_force(tmp_path: Path) -> None:
    """`run --log` is checked up front, but the logger creates the file seconds later (when the device answers): a
    log another run created meanwhile is not truncated; with --force (replace) it is."""
    from furuta_rt.io.mcap_read import read_log
    from furuta_rt.runtime.logger import LogSetup, TickLog

    path = tmp_path / "run.mcap"
    path.write_bytes(MINE)
    log = TickLog(LogSetup(path=str(path), rig=load_rig("thesis")))
    with pytest.raises(UserError, match=r"run\.mcap"):
        log.open({})
    assert path.read_bytes() == MINE
    log.close()  # the run ends without a writer: the file is still not replaced
    assert path.read_bytes() == MINE
    log = TickLog(LogSetup(path=str(path), rig=load_rig("thesis"), replace=True))
    log.open({})
    log.close()
    assert read_log(path, timing=False).n_ticks == 0 and path.read_bytes()[:5] == b"\x89MCAP"


def test_repair_in_place_does_not_replace_an_earlier_backup(tmp_path: Path, inputs: dict[str, Path]) -> None:
    """`repair LOG` keeps the original as LOG.bak: a LOG.bak already there (the original of an earlier repair) is
    refused, both files unchanged; with --force the new original replaces it."""
    torn = tmp_path / "run.mcap"
    torn.write_bytes(inputs["log"].read_bytes()[:-1000])  # every chunk, the summary cut
    bak = tmp_path / "run.mcap.bak"
    bak.write_bytes(MINE)
    before = torn.read_bytes()
    proc = _cli(tmp_path, "repair", "run.mcap")
    _refused(proc, "the backup", "run.mcap.bak")
    assert torn.read_bytes() == before and bak.read_bytes() == MINE
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.mcap", "run.mcap.bak"]
    proc = _cli(tmp_path, "repair", "run.mcap", "--force")
    assert proc.returncode == 0, proc.stderr
    assert bak.read_bytes() == before
    from furuta_rt.io.mcap_read import read_log

    assert read_log(torn).n_ticks == 1000


# ------------------------------------------------------------------ the other tools that write a file the user names
TOOLS = {  # argv (after the interpreter), the existing output (a file, or a directory holding one)
    "hil_mock_stats": (["-m", "hil_mock", "--pty", "--duration", "1", "--stats-json", "old.json"], "old.json"),
    "bench": (["-m", "scripts.bench_sections", "--only", "replay", "--json", "old.json"], "old.json"),
    "bench_diagnose": (["scripts/bench_diagnose", "--quick", "--json", "old.json"], "old.json"),
    "bench_independent": (["scripts/bench_independent", "--json", "old.json"], "old.json"),
    "fit_steps": (["scripts/fit_steps", "--json", "old.json"], "old.json"),
    "reproduce_thesis": (["-m", "furuta_rt.analysis.reproduction", "--quick", "--out", "figs"], "figs/fig9.png"),
    "chaos_keep": (["scripts/chaos", "--only", "exits", "--keep", "figs"], "figs/fig9.png"),
}


@pytest.mark.parametrize("tool", list(TOOLS))
def test_the_other_tools_refuse_an_existing_output_before_any_work(tmp_path: Path, tool: str) -> None:
    """hil-mock --stats-json, the benchmarks' --json, fit_steps --json, reproduce_thesis --out DIR (another than the
    repository's docs/figures) and chaos --keep DIR: exit 2, one line, the user's file as it was, nothing started."""
    import sys

    from test_reliability_harness import ROOT

    argv, existing = TOOLS[tool]
    target = tmp_path / existing
    target.parent.mkdir(exist_ok=True)
    target.write_bytes(MINE)
    argv = [str(ROOT / a) if a.startswith("scripts/") else a for a in argv]
    argv = [str(tmp_path / a) if a in ("old.json", "figs") else a for a in argv]
    proc = subprocess.run([sys.executable, *argv], cwd=ROOT, capture_output=True, text=True, timeout=120)
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert proc.returncode == 2 and len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr + proc.stdout
    assert str(target if target.name == "old.json" else target.parent) in lines[0] and "error" in lines[0], lines[0]
    assert proc.stdout.strip() == "", proc.stdout  # nothing ran
    assert target.read_bytes() == MINE
    written = sorted(str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*"))
    assert written == (["figs", existing] if "/" in existing else [existing])  # nothing written beside it


def test_a_link_keeps_pointing_at_the_replaced_file_and_a_device_is_written_into(tmp_path: Path) -> None:
    real = tmp_path / "real.csv"
    real.write_bytes(MINE)
    link = tmp_path / "link.csv"
    link.symlink_to(real)
    with pytest.raises(UserError, match="already exists"):
        claim_outputs([("--csv", link)], force=False)
    with replace_when_done(link, overwrite=True, flag="--csv") as tmp:
        tmp.write_text("new\n")
    assert link.is_symlink() and real.read_text() == "new\n"
    claim_outputs([("--csv", "/dev/null")], force=False)  # nothing there to lose: not refused, not replaced
    with replace_when_done("/dev/null", overwrite=False, flag="--csv") as tmp:
        assert tmp == Path("/dev/null")
        tmp.write_text("discarded\n")
    assert Path("/dev/null").is_char_device()
