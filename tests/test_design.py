"""Eq. 7 gains, python-control place/LQR cross-checks and the sampled-loop analysis."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from furuta_rt.cli import main
from furuta_rt.config import load_rig
from furuta_rt.controller.design import (
    characteristic_polynomial,
    lqr_gains,
    place_gains,
    pole_placement_gains,
    target_poles,
    target_polynomial,
)
from furuta_rt.controller.loop_analysis import analyze, minimum_stable_cutoff
from furuta_rt.model.plant import FurutaPlant

THESIS_L = [19.92, 3.230, 0.7274, 0.4850]


def test_eq7_gains_for_default_rig(thesis_rig) -> None:
    L = pole_placement_gains(thesis_rig.lumped())
    np.testing.assert_allclose(L, THESIS_L, rtol=1e-3)


def test_eq7_agrees_with_place_and_places_the_poles(thesis_rig) -> None:
    p = thesis_rig.lumped()
    plant = FurutaPlant(p)
    for w1, w2, z1, z2 in [(3, 7, 0.7, 0.7), (2, 5, 0.5, 0.9), (4, 10, 0.7, 0.7)]:
        L = pole_placement_gains(p, w1, w2, z1, z2)
        np.testing.assert_allclose(place_gains(plant, target_poles(w1, w2, z1, z2)), L, rtol=1e-6)
        np.testing.assert_allclose(characteristic_polynomial(p, L), target_polynomial(w1, w2, z1, z2), rtol=1e-9, atol=1e-9)
        A, B = plant.linearize()
        poles = np.sort_complex(np.linalg.eigvals(A + B @ L.reshape(1, 4)))
        np.testing.assert_allclose(poles, np.sort_complex(target_poles(w1, w2, z1, z2)), rtol=1e-5)


def test_lqr_stabilises(thesis_rig) -> None:
    plant = FurutaPlant(thesis_rig.lumped())
    L = lqr_gains(plant, [100, 1, 10, 1], 10.0)
    A, B = plant.linearize()
    assert np.all(np.linalg.eigvals(A + B @ L.reshape(1, 4)).real < 0)


def test_bessel_50_is_stable_and_15_is_not(thesis_rig) -> None:
    assert analyze(thesis_rig).stable
    r = thesis_rig.model_copy(deep=True)
    r.sensors.bessel_cutoff = 15.0
    rep = analyze(r)
    assert not rep.stable
    assert any("Bessel cutoff 15" in n for n in rep.notes)
    cutoff = minimum_stable_cutoff(thesis_rig)
    assert cutoff is not None and 25.0 < cutoff < 40.0


def test_gain_margin_brackets_one(thesis_rig) -> None:
    rep = analyze(thesis_rig)
    assert 0.0 < rep.gain_margin_down < 1.0 < rep.gain_margin_up
    assert 0.0 < rep.phase_margin_deg < 90.0


def test_design_json(capsys) -> None:
    assert main(["design", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    np.testing.assert_allclose(out["L"], [19.9216, 3.22999, 0.727427, 0.484951], rtol=1e-3)
    assert len(out["poles"]) >= 4 and all(len(p) == 2 for p in out["poles"])
    assert out["stable"] is True


def test_design_json_reports_unstable_filter(tmp_path, capsys) -> None:
    text = (load_rig.__module__ and "")  # noqa: F841 - keep import use explicit below
    cfg = tmp_path / "slow_filter.toml"
    cfg.write_text(
        '[plant]\nparametrisation="thesis"\nl=0.413\nr=0.235\nM=0.01\nm=0.02\nJp=0.0009\nJ=0.05\n'
        "[sensors]\nbessel_cutoff = 15.0\n"
    )
    assert main(["design", "--config", str(cfg), "--json"]) == 1
    out = json.loads(capsys.readouterr().out)
    assert out["stable"] is False
    assert 25 < out["minimum_stable_cutoff"] < 40
    assert any("Bessel" in n for n in out["notes"])


@pytest.mark.parametrize("rig", ["qube_servo2", "macstepien"])
def test_shipped_rigs_design(rig: str, capsys) -> None:
    assert main(["design", "--config", rig, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["stable"]


def test_design_output_at_160_columns(tmp_path, capsys, monkeypatch) -> None:
    """The pole table's title is one line, each complex pair one row (±im), and an unstable loop has no margins."""
    monkeypatch.setenv("COLUMNS", "160")
    assert main(["design"]) == 0
    out = capsys.readouterr().out
    assert any(line.startswith("closed-loop poles (plant + filter + observer + command delay") for line in out.splitlines())
    rows = [line for line in out.splitlines() if line.startswith("│")]
    ims = [line.split("│")[2].strip() for line in rows]
    res = [line.split("│")[1].strip() for line in rows]
    assert all(im == "0" or im.startswith("±") for im in ims) and len(res) == len(set(res))  # a pair: one row
    assert "stable for loop gain" in out
    thesis = (Path(__file__).resolve().parents[1] / "furuta_rt" / "rigs" / "thesis.toml").read_text()
    rig = tmp_path / "slow_filter.toml"
    rig.write_text(re.sub(r"(?m)^bessel_cutoff = .*$", "bessel_cutoff = 15.0", thesis))
    assert main(["design", "--config", str(rig)]) == 1
    out = capsys.readouterr().out
    assert "closed loop UNSTABLE" in out and "stable for loop gain" not in out and "margins: none" in out


def test_design_help_has_a_description() -> None:
    from furuta_rt.cli import build_parser

    sub = next(a for a in build_parser()._actions if getattr(a, "choices", None) and "design" in a.choices)
    assert "closed-loop poles" in (sub.choices["design"].description or "")
