"""Issue 19's HIL tests: from a diagnosis to compensation, and adaptive Coulomb compensation, through the real
daemon and hil_mock over a real pty (a hidden arm Coulomb friction of 0.35 N m in the mock).

(a) a 30 s run without compensation → `furuta-rt diagnose --json` on its log → `run --comp-from` the report:
    std θ and std φ at least 5× lower than without compensation, and within 20 % of a compensator given the
    true value; the summary, the summary JSON and the log's metadata say where the parameters came from.
(b) `--comp adaptive` starting from F̂c = 0 converges within 10 % of 0.35 N m (in ~1.3 s); once converged
    (from 7 s, when the decaying limit cycle of the first seconds, ~4 s a period, has died out) its std θ and
    std φ are within 20 % of (not more than 1.2× those of) the matched fixed compensator over the same
    stretch; after friction_step@15:Fc=0.5 the estimate re-converges within 10 % of 0.5 N m (time printed).
    The estimate is read per tick from
    /furuta/compensation; @mcap/core (node) counts one message per tick.

The mock runs in lockstep pacing (each device tick waits for the previous COMMAND), as the friction test of
test_run_hil.py: the physics is the same whatever the machine's load, and 30 s of device time take ~10 s.
Each run's log replays bit for bit (the adaptive law included).
"""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from test_compensation import settled_after
from test_reliability_harness import FURUTA_RT, LOCKSTEP, ROOT, independent_mcap_counts, read_summary, traceback_free
from test_run_hil import mock_run, steady

from furuta_rt.config import load_rig
from furuta_rt.io import log_schema as ls
from furuta_rt.io.mcap_read import read_log
from furuta_rt.io.rig_toml import rig_to_toml
from furuta_rt.replay.core import replay_log

pytestmark = pytest.mark.hil
RATE = 500
FC = 0.35
HIDDEN = ["--mock-effect", f"arm_coulomb.Fc={FC}", LOCKSTEP]
SETTLE_S = 4.0  # statistics from this long after balancing began (the adaptive estimate is within 10 % by then)


def true_value_rig(tmp: Path) -> Path:
    """The thesis rig with its Coulomb compensation given the mock's true Fc (the config's is 0.3 N m)."""
    rig = load_rig("thesis")
    comp = rig.compensation.model_copy(update={"coulomb": rig.compensation.coulomb.model_copy(update={"Fc": FC})})
    path = tmp / "rig_true_fc.toml"
    path.write_text(rig_to_toml(rig.model_copy(update={"compensation": comp})))
    return path


def finish(tmp: Path, name: str, d: object, seconds: float) -> tuple[float, float]:
    """Wait for a run; exit 0, no traceback, every tick logged and replayed bit for bit; (std θ, std φ) from
    SETTLE_S after balancing began."""
    rc = d.wait(timeout=240)  # type: ignore[attr-defined]
    assert rc == 0 and traceback_free(d.stderr), f"{name}: exit {rc}\n{d.stderr}\n{d.stdout}"  # type: ignore[attr-defined]
    log = read_log(tmp / name / "run.mcap")
    assert log.n_ticks == round(seconds * RATE) and replay_log(log).exact, f"{name}: log/replay"
    st = steady(log, SETTLE_S)
    return float(np.std(st["theta"])), float(np.std(st["phi"]))


def test_comp_from_the_diagnosis_of_an_uncompensated_run(tmp_path: Path) -> None:
    none = mock_run(tmp_path, "none", 30.0, "--comp", "none", *HIDDEN)
    th0, ph0 = finish(tmp_path, "none", none, 30.0)
    report = tmp_path / "report.json"
    diag = subprocess.run([*FURUTA_RT, "diagnose", str(tmp_path / "none" / "run.mcap"), "--json", str(report)],
                          capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert diag.returncode == 0 and traceback_free(diag.stderr), diag.stderr
    found = {e["name"]: e["params"] for e in json.loads(report.read_text())["effects"]}
    print(f"\ndiagnose found {found}")
    assert found.get("arm_coulomb", {}).get("Fc") == pytest.approx(FC, rel=0.1), found
    seconds = 12.0
    runs = {  # concurrently (lockstep: the load does not change the physics)
        "from_report": mock_run(tmp_path, "from_report", seconds, "--comp-from", str(report), *HIDDEN),
        "true_value": mock_run(tmp_path, "true_value", seconds, "--comp", "coulomb",
                               "--config", str(true_value_rig(tmp_path)), *HIDDEN),
    }
    (th1, ph1), (th2, ph2) = (finish(tmp_path, name, d, seconds) for name, d in runs.items())
    print(f"std θ: none {th0:.5f}, --comp-from {th1:.5f} ({th0 / th1:.1f}× lower), true Fc {th2:.5f} "
          f"(ratio {th1 / th2:.3f}); std φ: none {ph0:.4f}, --comp-from {ph1:.4f} ({ph0 / ph1:.1f}× lower), "
          f"true Fc {ph2:.4f} (ratio {ph1 / ph2:.3f})")
    assert th0 / th1 >= 5.0 and ph0 / ph1 >= 5.0
    assert th1 / th2 == pytest.approx(1.0, abs=0.2) and ph1 / ph2 == pytest.approx(1.0, abs=0.2)
    # where the parameters came from: the summary, its JSON, the log's run metadata; the logged rig has them
    fc = found["arm_coulomb"]["Fc"]
    out = runs["from_report"].stdout
    assert f"compensation: coulomb from diagnose report {report}" in out and f"Fc {fc:.4g}" in out, out
    assert read_summary(tmp_path / "from_report")["comp_source"].startswith(f"coulomb from diagnose report {report}")
    log = read_log(tmp_path / "from_report" / "run.mcap")
    assert log.mode == "coulomb" and str(report) in log.run["comp_source"]
    assert log.rig is not None and log.rig.compensation.coulomb.Fc == fc


def test_adaptive_from_zero_converges_and_follows_a_friction_step(tmp_path: Path) -> None:
    seconds, step_at, fc_after, converged_s = 22.0, 15.0, 0.5, 7.0
    matched_s = step_at
    runs = {
        "adaptive": mock_run(tmp_path, "adaptive", seconds, "--comp", "adaptive", *HIDDEN,
                             "--mock-fault", f"friction_step@{step_at:g}:Fc={fc_after:g}"),
        "matched": mock_run(tmp_path, "matched", matched_s, "--comp", "coulomb",
                            "--config", str(true_value_rig(tmp_path)), *HIDDEN),
    }
    finish(tmp_path, "adaptive", runs["adaptive"], seconds)
    finish(tmp_path, "matched", runs["matched"], matched_s)
    path = tmp_path / "adaptive" / "run.mcap"
    assert independent_mcap_counts(path)["topics"][ls.COMPENSATION_TOPIC] == seconds * RATE
    with path.open("rb") as fh:
        comp = {m.sequence: json.loads(m.data)["fc_hat"]
                for _, _, m in make_reader(fh).iter_messages(topics=[ls.COMPENSATION_TOPIC])}
    log = read_log(path)
    tk = log.ticks
    t = tk["t"] - tk["t"][0]
    fc = np.array([comp[int(s)] for s in tk["seq"]])
    assert fc[0] == 0.0 and "friction steps 1 (arm Coulomb now 0.5 N m)" in runs["adaptive"].stdout
    before, after = t < step_at, t >= step_at + 0.01
    t_conv = settled_after(t[before], fc[before], FC)
    t_re = settled_after(t[after], fc[after], fc_after) - step_at
    # std θ/φ once converged, over the same stretch of both runs: converged_s after balancing began → the step
    matched = read_log(tmp_path / "matched" / "run.mcap").ticks

    def stats(ticks: dict[str, np.ndarray], start: float) -> tuple[float, float]:
        tt = ticks["t"] - ticks["t"][0]
        bal = ticks["state"] == "balancing"
        w = bal & (tt >= tt[np.flatnonzero(bal)[0]] + start) & (tt < step_at)
        return float(np.std(ticks["theta"][w])), float(np.std(ticks["phi"][w]))

    (th_a, ph_a), (th_m, ph_m) = stats(tk, converged_s), stats(matched, converged_s)
    (th_a4, ph_a4), (th_m4, ph_m4) = stats(tk, SETTLE_S), stats(matched, SETTLE_S)
    print(f"\nadaptive: F̂c within 10 % of {FC} from t = {t_conv:.2f} s (at the step {fc[before][-1]:.4f} N m); "
          f"after the step to {fc_after} N m within 10 % {t_re:.2f} s later (end {fc[-1]:.4f} N m); "
          f"std θ {th_a:.5f} vs matched {th_m:.5f} ({th_a / th_m:.2f}×), std φ {ph_a:.4f} vs matched {ph_m:.4f} "
          f"({ph_a / ph_m:.2f}×) from {converged_s:g} s; from {SETTLE_S:g} s: {th_a4 / th_m4:.2f}× and "
          f"{ph_a4 / ph_m4:.2f}×")
    assert t_conv <= SETTLE_S, f"F̂c per second: {np.round(fc[before][::RATE], 3)}"
    assert t_re <= 6.0, f"F̂c per second after the step: {np.round(fc[after][::RATE], 3)}"
    assert th_a <= 1.2 * th_m and ph_a <= 1.2 * ph_m
    assert "adaptive Coulomb estimate at the end: Fc" in runs["adaptive"].stdout
