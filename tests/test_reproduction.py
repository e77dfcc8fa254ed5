"""scripts/reproduce_thesis in quick mode: the figures and the table are written, the no-compensation
loop has the thesis' limit cycle, and every matched compensation cuts std(θ) and std(φ) clearly."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from furuta_rt.analysis.reproduction import (
    CALIBRATED_FC,
    THESIS_STD,
    calibrate_coulomb,
    main,
    run_mode,
    table_markdown,
)

FIGURES = (
    "fig09_nyquist.png",
    "fig11_feedbacks.png",
    "fig12_no_compensation_states.png",
    "fig13_coulomb_friction.png",
    "fig14_simulation_vs_thesis.png",
    "fig15_compensation.png",
    "fig16_lugre.png",
)


@pytest.fixture(scope="module")
def quick(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("repro")
    assert main(["--quick", "--out", str(out)]) == 0
    return out, json.loads((out / "reproduction.json").read_text())


def test_quick_run_writes_figures_and_table(quick: tuple[Path, dict]) -> None:
    out, summary = quick
    for name in FIGURES:
        size = (out / name).stat().st_size
        assert 5_000 < size < 200_000, name
    table = (out / "reproduction_table.md").read_text()
    for mode, (th, ph, u) in THESIS_STD.items():
        assert f"| {mode} |" in table and f"| {th:g} |" in table and f"| {ph:g} |" in table and f"| {u:g} |" in table
    assert summary["fc"] == CALIBRATED_FC


def test_section4_cases_in_the_summary(quick: tuple[Path, dict]) -> None:
    s4 = quick[1]["section4"]
    assert [c["limit_cycle"] for c in s4.values()] == [c["thesis_says_limit_cycle"] for c in s4.values()]
    # the simulations show what the thesis describes for 4.3: a drift at φ̇ = Fc/l4 with l4 = 1, and an
    # oscillation riding on a drift Fc/7 with l4 = 7
    by_gain = {tuple(c["gains"]): c for c in s4.values()}
    assert f"drifts at {CALIBRATED_FC:.2g}" in by_gain[(60.0, 20.0, 0.0, 1.0)]["simulation"]
    assert "oscillates" in by_gain[(60.0, 20.0, 0.0, 7.0)]["simulation"]
    assert "drifts at 0.16" in by_gain[(60.0, 20.0, 0.0, 7.0)]["simulation"]


def test_no_compensation_matches_the_thesis_limit_cycle(quick: tuple[Path, dict]) -> None:
    none = quick[1]["table"]["none"]
    assert not none["fell"]
    assert none["std_theta"] == pytest.approx(THESIS_STD["none"][0], rel=0.2)
    assert none["std_phi"] == pytest.approx(THESIS_STD["none"][1], rel=0.25)
    assert none["stuck_fraction"] > 0.1  # a stick-slip limit cycle


@pytest.mark.parametrize("mode", ["coulomb", "stiction", "lugre"])
def test_matched_compensation_cuts_the_limit_cycle(quick: tuple[Path, dict], mode: str) -> None:
    t = quick[1]["table"]
    assert not t[mode]["fell"]
    assert t["none"]["std_theta"] / t[mode]["std_theta"] > 8.0
    assert t["none"]["std_phi"] / t[mode]["std_phi"] > 20.0
    assert t[mode]["std_u"] < t["none"]["std_u"]


def test_calibration_prefers_the_level_that_matches(thesis_rig) -> None:
    cal = calibrate_coulomb(thesis_rig, [0.4, 1.1], duration=14.0, transient=5.0)
    assert cal.fc == 1.1
    assert cal.scan[0][1].std_phi < 0.6 * cal.scan[1][1].std_phi  # amplitude grows with Fc


def test_table_marks_a_fall(thesis_rig) -> None:
    _, st = run_mode(thesis_rig, 1.4, "none", 8.0, 2.0)
    assert st.fell
    assert "none (fell)" in table_markdown({"none": st}, 1.4)


def test_beyond_the_thesis_rows_match_the_known_friction_compensator(quick: tuple[Path, dict]) -> None:
    """Issue 19's rows: compensation from diagnose's report of the uncompensated run is as good as the Coulomb
    compensator told the simulated friction (within 20 %); adaptive from F̂c = 0 ends within 10 % of it and
    cuts the limit cycle as the matched compensators do (its statistics here start 6 s in, while it still
    converges: the 20 % comparison once converged is tests/test_compensation_hil.py's)."""
    out, summary = quick
    beyond = summary["beyond_thesis"]
    report = json.loads(Path(beyond["comp_from"]["report"]).read_text())
    found = {e["name"]: e["params"] for e in report["effects"]}
    assert found["arm_coulomb"]["Fc"] == pytest.approx(CALIBRATED_FC, rel=0.05)
    assert beyond["adaptive_final_fc"] == pytest.approx(CALIBRATED_FC, rel=0.1)
    t = summary["table"]
    rows = {key.split(" ")[0].rstrip(","): row for key, row in t.items() if "--comp-from" in key or key.startswith("adaptive")}
    assert set(rows) == {"coulomb", "adaptive"}
    assert not rows["coulomb"]["fell"]
    assert rows["coulomb"]["std_theta"] == pytest.approx(t["coulomb"]["std_theta"], rel=0.2)
    assert rows["coulomb"]["std_phi"] == pytest.approx(t["coulomb"]["std_phi"], rel=0.2)
    adaptive = rows["adaptive"]
    assert not adaptive["fell"]
    assert t["none"]["std_theta"] / adaptive["std_theta"] > 8.0 and t["none"]["std_phi"] / adaptive["std_phi"] > 20.0
    table = (out / "reproduction_table.md").read_text()
    assert "--comp-from diagnose" in table and "adaptive from F̂c = 0" in table
