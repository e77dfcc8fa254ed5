"""`furuta-rt diagnose --report DIR` (issue 13, item 5): a self-contained report.html a person reads, its figures
≥ 1000 px wide, rendered in headless Chromium (not blank, every image loads); a user's files never overwritten."""

from __future__ import annotations

import dataclasses
import json
import math
import re
import shutil
import subprocess
from html import escape
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from benchmarks import suite
from furuta_rt.cli import main
from furuta_rt.config import load_rig
from furuta_rt.diagnose.report.page import html_page
from furuta_rt.io.csv import write_csv
from furuta_rt.recording import Recording

CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                  "--disable-component-update", "--disable-sync", "--no-first-run"]


@pytest.fixture(scope="module")
def reports(tmp_path_factory) -> dict[str, Path]:
    """Reports of two recordings: balancing with an arm reference (both equations assessed), and a pendulum
    swinging under a still arm (the arm equation not assessed)."""
    rig = load_rig("thesis")
    tmp = tmp_path_factory.mktemp("reports")
    case = next(c for c in suite.quick_cases() if c.name == "arm_coulomb")
    moving = suite.generate(dataclasses.replace(case, duration=10.0), rig, tmp / "cache")
    t = np.arange(4000) * 0.002
    z = np.zeros_like(t)
    swing = Recording(t=t, theta=math.pi + 0.5 * np.cos(2 * math.pi * 0.9 * t) * np.exp(-t / 5), phi=z, u=z)
    out = {}
    for name, rec in (("moving", moving), ("arm_still", swing)):
        path = tmp / f"{name}.csv"
        write_csv(rec, path)
        out[name] = tmp / f"report_{name}"
        assert main(["diagnose", str(path), "--no-closed-loop", "--report", str(out[name])]) == 0
    return out


def test_report_directory_is_self_contained(reports) -> None:
    for d in reports.values():
        page = (d / "report.html").read_text()
        srcs = re.findall(r'<img src="([^"]+)"', page)
        assert srcs and "residuals.png" in srcs and "where.png" in srcs
        for src in srcs:
            assert "/" not in src and (d / src).is_file()  # linked relatively, beside the page
            assert Image.open(d / src).size[0] >= 1000
        data = json.loads((d / "diagnosis.json").read_text())
        assert escape(data.get("summary") or data["located"]) in page  # the summary line, first
        assert page.index('class="summary"') < page.index("<img")


def test_an_equation_not_assessed_is_said_not_left_empty(reports) -> None:
    page = (reports["arm_still"] / "report.html").read_text()
    assert "the arm hardly moves" in page
    where = np.asarray(Image.open(reports["arm_still"] / "where.png").convert("L"), dtype=float)
    top = where[: where.shape[0] // 2]
    assert (top < 128).mean() > 0.001  # the upper (arm) panel carries its text, not an empty frame


def test_text_is_escaped_and_absent_keys_are_left_out() -> None:
    data = {"rig": "<rig>", "located": "a & b", "notes": ["<script>alert(1)</script>"],
            "equations": {"arm": {"rows": 10, "verdict": "unexplained",
                                  "unexplained": {"share": 0.2, "where": ["at <low> speed"], "possible_causes": [
                                      {"cause": "pendulum inertia", "value": 1.2, "se": 0.1, "removes": 0.8}]}}}}
    page = html_page(data, [], ["x < y"])
    assert "<script>alert" not in page and "&lt;script&gt;" in page and "&lt;rig&gt;" in page
    assert "a &amp; b" in page and "at &lt;low&gt; speed" in page and "pendulum inertia" in page
    assert "unexplained" in page and "Held-out prediction" not in page  # no fit key: no fit section


def test_the_page_tells_what_the_text_tells() -> None:
    """No impossible identification presented as a finding, one row per quantity, the text report's signs and
    number formats (a held-out error that fell by 100 % is −100.0 % in both; t = 12346, not 1.23e+04)."""
    data = {"rig": "thesis", "summary": "explained",
            "equations": {"arm": {"rows": 5000, "verdict": "explained", "cv_gain": 1.0}},
            "effects": [{"name": "arm_coulomb", "params": {"Fc": 0.3}}],
            "evidence": [{"name": "arm_coulomb", "equation": "arm", "se": {"Fc": 0.001}, "source": "inverse dynamics",
                          "cv_gain": 1.0, "t": 12345.6}],
            "identification": {"parameters": {"arm_inertia": {"value": -0.0015, "se": 2e-4, "pinned": False}},
                               "unphysical": "the joint fit gives arm inertia -0.0015 (≤ 0, impossible): this recording "
                                             "does not pin the arm's gain, inertia and damping, nor their combinations"}}
    page = html_page(data, [], ["arm_coulomb: Fc = 0.3 ± 0.001   [arm equation, −100.0 %, t = 12346]"])
    body = page.split("<h2>Text report</h2>")[0]
    assert "−100.0 %" in body and ">100.0 %" not in body and "12346" in body and "e+04" not in body
    ident = body.split("<h2>Identification</h2>")[1]
    assert "Not identified:" in ident and "<table>" not in ident  # the impossible values are the reason, not a row
    both = {"arm_viscous": {"value": 0.02, "se": 0.001, "pinned": True},
            "arm_damping": {"value": 0.02, "se": 0.001, "pinned": True},
            "input_gain": {"value": 0.98, "se": 0.01, "pinned": True, "selected": True},
            "arm_inertia": {"value": 0.05, "se": 0.002, "pinned": True}}
    page = html_page({**data, "identification": {"parameters": both}}, [], [])
    ident = page.split("<h2>Identification</h2>")[1].split("</table>")[0]
    assert ident.count("<tr>") == 3 and "arm_viscous = arm_damping" in ident  # header + two quantities
    assert "input_gain" not in ident  # reported, with its value, under Found
    worse = html_page({**data, "equations": {"arm": {"rows": 10, "cv_gain": -0.05}}}, [], [])
    assert "+5.0 %" in worse


def test_a_users_directory_is_never_overwritten(reports, tmp_path, capsys) -> None:
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "summary.md").write_text("my notes")
    src = next(iter(reports.values())).parent / "moving.csv"
    assert main(["diagnose", str(src), "--no-closed-loop", "--report", str(mine)]) == 2
    err = capsys.readouterr().err
    assert "not a furuta-rt report" in err and err.count("\n") == 1
    assert (mine / "summary.md").read_text() == "my notes" and sorted(p.name for p in mine.iterdir()) == ["summary.md"]


def test_report_renders_in_headless_chromium(reports, tmp_path) -> None:
    exe = shutil.which("chromium") or shutil.which("chromium-browser")
    if exe is None:
        pytest.skip("chromium is not installed (Debian package 'chromium'; scripts/test installs it when run as root)")
    for name, d in reports.items():
        # a copy of the page beside it with a probe that records every image's natural width once loaded
        probe = d / "probe.html"
        probe.write_text((d / "report.html").read_text().replace("</body>", (
            "<script>window.addEventListener('load', () => { document.body.setAttribute('data-images', "
            "JSON.stringify([...document.images].map(i => [i.getAttribute('src'), i.naturalWidth]))); "
            "const pre = document.querySelector('pre'); document.body.setAttribute('data-pre', "
            "JSON.stringify([pre.scrollWidth, pre.clientWidth])); });</script></body>")))
        base = [exe, *CHROMIUM_FLAGS, f"--user-data-dir={tmp_path / ('profile_' + name)}", "--virtual-time-budget=10000"]
        dom = subprocess.run([*base, "--dump-dom", probe.as_uri()], capture_output=True, text=True, timeout=120).stdout
        m = re.search(r'data-images="([^"]*)"', dom)
        assert m, f"{name}: the page did not finish loading in Chromium"
        images = json.loads(m.group(1).replace("&quot;", '"'))
        assert images and all(w >= 1000 for _, w in images), images
        scroll, width = json.loads(re.search(r'data-pre="([^"]*)"', dom).group(1))
        assert scroll <= width, f"{name}: the text report needs a horizontal scrollbar ({scroll} > {width} px)"
        shot = tmp_path / f"{name}.png"
        subprocess.run([*base, "--window-size=1200,2400", f"--screenshot={shot}", (d / "report.html").as_uri()],
                       capture_output=True, timeout=120, check=True)
        px = np.asarray(Image.open(shot).convert("L"), dtype=float)
        assert px.std() > 10 and (px < 200).mean() > 0.02, f"{name}: the rendered page looks blank"
        probe.unlink()
