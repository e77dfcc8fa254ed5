"""A recording with gaps (rows missing, a time column that jumps, rows with a missing value) is diagnosed as the
stretches between them (furuta_rt.diagnose.segments): each prepared alone, fitted together, what was lost said in
one line. Through the real CLI on CSV files, against the suite's seeded simulated recordings."""

from __future__ import annotations

import dataclasses
import functools
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from benchmarks import suite
from furuta_rt.config import load_rig
from furuta_rt.diagnose import Diagnosis, Options, diagnose
from furuta_rt.diagnose.segments import GAP_PERIODS, split_at_gaps
from furuta_rt.io.csv import write_csv
from furuta_rt.io.mcap_log import write_recording_mcap
from furuta_rt.recording import Recording

SECONDS = 20.0
HOLE_S = 0.2  # each cut
LOST_S = 0.3 + HOLE_S + HOLE_S + 1.0  # three holes, and the 1 s stretch after the last (too short for the filter)


def cli(*args: str) -> tuple[int, str, str]:
    exe = Path(sys.executable).with_name("furuta-rt")
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-c", "import sys; from furuta_rt.cli import main; sys.exit(main())"]
    p = subprocess.run([*cmd, "diagnose", *args], capture_output=True, text=True, timeout=600)
    return p.returncode, p.stdout, p.stderr


@functools.cache
def recording(name: str) -> Recording:
    case = next(c for c in suite.quick_cases() if c.name == name)
    return suite.generate(dataclasses.replace(case, duration=SECONDS), load_rig("thesis"))


def with_gaps(rec: Recording) -> Recording:
    """Three gaps: 0.3 s of rows missing at 5 s (the time column jumps), 0.2 s of all-NaN rows at 10 s, 0.2 s of NaN
    in φ alone at 18.8 s (the 1 s after it is too short for the filter)."""
    at = lambda s: int(np.searchsorted(rec.t, s))  # noqa: E731
    cols = {k: np.array(getattr(rec, k), dtype=float) for k in ("t", "theta", "theta_dot", "phi", "u")}
    for k in ("theta", "theta_dot", "phi", "u"):
        cols[k][at(10.0):at(10.0 + HOLE_S)] = np.nan
    cols["phi"][at(18.8):at(18.8 + HOLE_S)] = np.nan
    keep = np.ones(len(rec.t), dtype=bool)
    keep[at(5.0):at(5.3)] = False
    return Recording(**{k: v[keep] for k, v in cols.items()}, meta=dict(rec.meta))


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("gaps")
    paths = {}
    for name in ("arm_coulomb", "null"):
        paths[name] = out / f"{name}_gaps.csv"
        write_csv(with_gaps(recording(name)), paths[name])
    return paths


def test_short_holes_are_filled_longer_ones_split() -> None:
    """Two missing rows stay inside a stretch (prepare fills them); three are a gap, as is a jump of the time column
    by more than GAP_PERIODS periods; a recording without either is left whole."""
    rec = recording("null")
    assert split_at_gaps(rec).segments[0] is rec and split_at_gaps(rec).gaps == 0
    for rows, gaps in ((2, 0), (3, 1)):
        phi = rec.phi.copy()
        phi[4000:4000 + rows] = np.nan
        assert split_at_gaps(dataclasses.replace(rec, phi=phi)).gaps == gaps
    dt = rec.t[1] - rec.t[0]
    for jump, gaps in ((0.9 * GAP_PERIODS, 0), (1.1 * GAP_PERIODS, 1)):
        t = rec.t + np.where(np.arange(len(rec.t)) >= 4000, (jump - 1) * dt, 0.0)
        s = split_at_gaps(dataclasses.replace(rec, t=t))
        assert s.gaps == gaps and len(s.segments) == gaps + 1


@pytest.fixture(scope="module")
def gap_free() -> Diagnosis:
    full = diagnose(recording("arm_coulomb"), load_rig("thesis"), Options(closed_loop=False))
    assert full.names == ["arm_coulomb"]
    return full


def test_concealed_arm_friction_found_across_gaps(files, gap_free) -> None:
    """The arm's Coulomb friction is named from the three stretches, its level within 3 of the segmented fit's
    standard errors of the gap-free recording's (the stretches are a subset of the same data)."""
    full = gap_free
    code, out, err = cli(str(files["arm_coulomb"]), "--json", "-", "--no-closed-loop")
    assert code == 0 and "Traceback" not in err, err
    d = json.loads(out)
    assert [e["name"] for e in d["effects"]] == ["arm_coulomb"]
    fc, se, ref = d["effects"][0]["params"]["Fc"], d["evidence"][0]["se"]["Fc"], full.effects[0]
    assert abs(fc - ref.params["Fc"]) <= 3 * se, (fc, se, ref.params, ref.se)
    g = d["gaps"]
    assert (g["gaps"], len(g["segments"]), g["dropped"]) == (3, 3, 1)
    assert abs(g["lost_s"] - LOST_S) <= 4 * 0.002  # a sample's rounding at each cut
    # the time blocks stay within one stretch: the rows each stretch gave add up to the fit's
    assert len(d["rows"]["arm"]) == 3 and all(r > 0 for r in d["rows"]["arm"])


def test_null_with_gaps_names_nothing_and_says_what_was_lost(files) -> None:
    code, out, err = cli(str(files["null"]), "--no-closed-loop")
    assert code == 0 and "Traceback" not in err, err
    lines = out.splitlines()
    assert lines[0].startswith("3 gap(s) in the recording") and "3 segment(s) diagnosed, 1 too short" in lines[0]
    assert f"{LOST_S:.2f} s of {SECONDS:.2f} s lost" in lines[0], lines[0]
    assert "effects: none (the nominal model fits)" in out


def test_all_gaps_is_refused_in_one_line(tmp_path) -> None:
    """Stretches of 0.9 s between 0.1 s holes: none long enough for the filter; a file with no complete row."""
    rec = recording("null")
    keep = (rec.t % 1.0) < 0.9
    choppy = Recording(t=rec.t[keep], theta=rec.theta[keep], phi=rec.phi[keep], u=rec.u[keep],
                       theta_dot=rec.theta_dot[keep])
    empty = dataclasses.replace(rec, phi=np.full(len(rec.t), np.nan))
    for name, r, words in (("choppy", choppy, "19 gap(s) and no stretch between them of at least 2 s"),
                           ("empty", empty, "0 complete row(s)")):
        path = tmp_path / f"{name}.csv"
        write_csv(r, path)
        code, out, err = cli(str(path), "--no-closed-loop")
        assert code == 2 and err.count("\n") == 1 and words in err and not out, err


def test_page_refuses_a_split_recording_in_one_line(files, tmp_path) -> None:
    """The report page takes a continuous recording: one line, nothing written."""
    report = tmp_path / "report"
    code, out, err = cli(str(files["null"]), "--report", str(report), "--no-closed-loop")
    assert code == 2 and err.count("\n") == 1 and "splits into 3 segments at its gaps: use --json" in err and not out
    assert not report.exists() or not any(report.iterdir())


def test_joint_fit_takes_recordings_with_gaps_as_their_stretches(gap_free) -> None:
    """Two recordings of one rig with gaps fitted jointly (a designed experiment's log on a busy machine has them):
    each takes part as its stretches; the arm friction is found, its level within 3 se of the gap-free recording's
    alone; the rows are reported per recording (its stretches added), each recording's gaps among the notes."""
    from furuta_rt.diagnose.jointly import diagnose_joint

    case = next(c for c in suite.quick_cases() if c.name == "arm_coulomb")
    again = suite.generate(dataclasses.replace(case, duration=SECONDS, seed=case.seed + 1), load_rig("thesis"))
    j = diagnose_joint([("a", with_gaps(recording("arm_coulomb"))), ("b", with_gaps(again))], load_rig("thesis"),
                       Options(closed_loop=False))
    assert j.names == ["arm_coulomb"], j.names
    fc, ref = j.effects[0].params["Fc"], gap_free.effects[0]
    assert abs(fc - ref.params["Fc"]) <= 3 * ref.se["Fc"], (fc, ref.params, ref.se)
    assert len(j.rows["arm"]) == 2 and all(r > 0 for r in j.rows["arm"])
    assert sum("3 gap(s) in the recording" in n for n in j.notes) == 2, j.notes


def test_a_daemon_log_with_one_pause_is_diagnosed_as_two_stretches(gap_free, tmp_path) -> None:
    """A log of the daemon with one 60 ms pause (a busy machine): two stretches fitted together, the same friction."""
    rec = recording("arm_coulomb")
    keep = (rec.t < 10.0) | (rec.t >= 10.06)
    path = tmp_path / "paused.mcap"
    write_recording_mcap(Recording(t=rec.t[keep], theta=rec.theta[keep], phi=rec.phi[keep], u=rec.u[keep],
                                   theta_dot=rec.theta_dot[keep]), path, load_rig("thesis"))
    code, out, err = cli(str(path), "--json", "-", "--no-closed-loop")
    assert code == 0 and "Traceback" not in err, err
    d = json.loads(out)
    assert (d["gaps"]["gaps"], len(d["gaps"]["segments"]), d["gaps"]["dropped"]) == (1, 2, 0)
    assert [e["name"] for e in d["effects"]] == ["arm_coulomb"]
    fc, se = d["effects"][0]["params"]["Fc"], d["evidence"][0]["se"]["Fc"]
    assert abs(fc - gap_free.effects[0].params["Fc"]) <= 3 * se, (fc, se)
