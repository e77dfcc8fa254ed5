"""`furuta-rt diagnose` on a matrix of recording shapes (issue 13, item 4): each gives a one-line error that says
what to do, or a diagnosis that says what it repaired — never a traceback. Through the CLI (a subprocess where it
refuses, its ``main`` in-process where it diagnoses), plus a property-based test over shapes in-process."""

from __future__ import annotations

import dataclasses
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from benchmarks import suite
from furuta_rt.cli import main
from furuta_rt.config import load_rig
from furuta_rt.diagnose import Options, diagnose
from furuta_rt.errors import UserError
from furuta_rt.io.csv import read_csv, write_csv
from furuta_rt.recording import Recording

FAST = Options(closed_loop=False, max_windows=8)
KEYS = {"effects", "equations", "fit", "notes", "located"}


@pytest.fixture(scope="module")
def rig():
    return load_rig("thesis")


@pytest.fixture(scope="module")
def base(rig, tmp_path_factory) -> Recording:
    """8 s of the suite's arm-Coulomb case: balancing with an arm reference (the arm moves, the command varies)."""
    case = next(c for c in suite.quick_cases() if c.name == "arm_coulomb")
    return suite.generate(dataclasses.replace(case, duration=8.0), rig, tmp_path_factory.mktemp("suite"))


def cli(*args: str) -> tuple[int, str, str]:
    exe = Path(sys.executable).with_name("furuta-rt")
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-c", "import sys; from furuta_rt.cli import main; sys.exit(main())"]
    p = subprocess.run([*cmd, "diagnose", *args], capture_output=True, text=True, timeout=300)
    return p.returncode, p.stdout, p.stderr


def shapes(base: Recording) -> dict[str, tuple[Recording, str]]:
    """name → (recording, what the CLI must say: 'ok:<a note's words>' or 'error:<words of the one-line error>')."""
    n, t = len(base), base.t
    rng = np.random.default_rng(1)

    def r(**kw: np.ndarray) -> Recording:
        return dataclasses.replace(base, **kw)

    def flipped(name: str, k: float) -> Recording:
        kw = {name: getattr(base, name) * k}
        if name == "theta" and base.theta_dot is not None:
            kw["theta_dot"] = base.theta_dot * k
        return r(**kw)

    mostly_zero = base.u.copy()
    mostly_zero[: 2 * n // 3] = 0.0
    isolated = base.theta.copy()
    isolated[rng.choice(np.arange(200, n - 200), 15, replace=False)] = np.nan
    long_gap = base.phi.copy()
    long_gap[1000:1200] = np.nan
    repeated = t.copy()
    repeated[500:503] = repeated[500]  # two stamps repeated: a longer run leaves a hole of 3+ samples, a gap
    jitter = np.sort(t + rng.uniform(-0.45, 0.45, n) * (t[1] - t[0]))
    backwards = t.copy()
    backwards[2000:] -= 1.0
    z = np.zeros(n)
    hanging = Recording(t=t, theta=math.pi + 2e-4 * rng.standard_normal(n), phi=z, u=z)
    swinging = Recording(t=t, theta=math.pi + 0.4 * np.cos(2 * math.pi * 0.9 * t) * np.exp(-t / 6), phi=z, u=z)
    return {
        "command zero on 2/3": (r(u=mostly_zero), "ok:"),
        "constant command": (r(u=np.full(n, 0.2)), "ok:the command is constant"),
        "shorter than 2 s": (base.slice(0, int(1.5 / (t[1] - t[0]))), "error:needs at least 2 s"),
        "isolated NaN rows": (r(theta=isolated), "ok:non-finite samples in 15 gap(s) filled"),
        "0.4 s of NaN": (r(phi=long_gap), "ok:1 gap(s) in the recording"),  # the 2 s before it: too short
        "repeated time stamps": (r(t=repeated), "ok:repeated time stamps"),
        "irregular time stamps": (r(t=jitter), "ok:resampled onto a uniform grid"),
        "time going backwards": (r(t=backwards), "error:not increasing"),
        "arm never moves": (swinging, "ok:the arm hardly moves"),
        "pendulum hanging throughout": (hanging, "ok:the command is constant"),
        "θ reversed": (flipped("theta", -1.0), "error:the sign of θ appears reversed relative to the rig"),
        "φ reversed": (flipped("phi", -1.0), "error:the sign of φ appears reversed relative to the rig"),
        "u reversed": (flipped("u", -1.0), "error:the sign of u appears reversed relative to the rig"),
        "θ in degrees": (flipped("theta", 180 / math.pi), "error:θ appears to be in degrees"),
        "φ in degrees": (flipped("phi", 180 / math.pi), "error:φ appears to be in degrees"),
        "hanging, θ in degrees": (dataclasses.replace(hanging, theta=hanging.theta * 180 / math.pi),
                                  "error:θ appears to be in degrees: the pendulum rests at θ = +180"),
    }


SHAPES = ("command zero on 2/3", "constant command", "shorter than 2 s", "isolated NaN rows", "0.4 s of NaN",
          "repeated time stamps", "irregular time stamps", "time going backwards", "arm never moves",
          "pendulum hanging throughout", "θ reversed", "φ reversed", "u reversed", "θ in degrees", "φ in degrees",
          "hanging, θ in degrees")


@pytest.fixture(scope="module")
def matrix(base, tmp_path_factory) -> dict[str, tuple[Path, str]]:
    out = tmp_path_factory.mktemp("shapes")
    cases = shapes(base)
    assert set(cases) == set(SHAPES)
    written = {}
    for i, (name, (rec, expect)) in enumerate(cases.items()):
        write_csv(rec, out / f"shape{i}.csv")
        written[name] = (out / f"shape{i}.csv", expect)
    return written


@pytest.mark.parametrize("name", SHAPES)
def test_shape_through_the_cli(matrix, name, capsys) -> None:
    """A refusal through a real process (its stderr is what a user reads: one line); a diagnosis through the same
    ``main`` in this process (an exception would fail the test as a traceback would), which spares a process start
    and the diagnosis' imports per shape."""
    path, expect = matrix[name]
    kind, words = expect.split(":", 1)
    if kind == "error":
        code, out, err = cli(str(path), "--json", "-", "--no-closed-loop")
        assert "Traceback" not in err
        assert code == 2 and err.count("\n") == 1 and words in err and not out, err
    else:
        code = main(["diagnose", str(path), "--json", "-", "--no-closed-loop"])
        out, err = capsys.readouterr()
        assert code == 0, err
        d = json.loads(out)
        assert set(d) >= KEYS
        assert not words or any(words in note for note in d["notes"]), d["notes"]


def test_a_reversed_column_is_diagnosed_once_flipped_back(base, tmp_path) -> None:
    """The fix the error names works: φ reversed, then --map phi.scale=-1 gives the diagnosis of the original."""
    path = tmp_path / "phi_reversed.csv"
    write_csv(dataclasses.replace(base, phi=-base.phi), path)
    code, _, err = cli(str(path), "--json", "-", "--no-closed-loop")
    assert code == 2 and "--map phi.scale=-1" in err
    code, out, err = cli(str(path), "--json", "-", "--no-closed-loop", "--map", "phi.scale=-1")
    assert code == 0, err
    assert [e["name"] for e in json.loads(out)["effects"]] == ["arm_coulomb"]
    code, out, _ = cli(str(path), "--json", "-", "--no-closed-loop", "--skip-convention-check")
    assert code == 0 and "arm_coulomb" not in [e["name"] for e in json.loads(out)["effects"]]


def test_empty_and_nan_cells_are_read_as_gaps_only_for_diagnose(tmp_path) -> None:
    """The CSV reader stays strict (convert, replay); diagnose reads empty / NaN cells and repeated times as gaps."""
    path = tmp_path / "gaps.csv"
    path.write_text("t,theta,phi,u\n0,0.1,0,0\n0.002,,0,0\n0.002,nan,0,0\n0.004,0.2,0,0\n")
    with pytest.raises(UserError, match="not a number"):
        read_csv(path)
    rec = read_csv(path, gaps=True)
    assert np.isnan(rec.theta[1]) and np.isnan(rec.theta[2]) and rec.theta[3] == 0.2 and rec.t[1] == rec.t[2]


@st.composite
def recording_shapes(draw: st.DrawFn, base: Recording) -> Recording:
    """A window of ``base`` (1–6 s) with NaN runs, timestamp jitter and repeats, a zero or constant command and a
    scaled or reversed column, each drawn or not."""
    dt = float(base.t[1] - base.t[0])
    n = int(draw(st.floats(1.0, 6.0)) / dt)
    a = draw(st.integers(0, len(base) - n))
    rec = base.slice(a, a + n)
    t, theta, phi, u = rec.t.copy(), rec.theta.copy(), rec.phi.copy(), rec.u.copy()
    for _ in range(draw(st.integers(0, 4))):  # NaN runs in one column
        col = draw(st.sampled_from([theta, phi, u]))
        i = draw(st.integers(0, n - 1))
        col[i : i + draw(st.integers(1, 60))] = np.nan
    if draw(st.booleans()):
        t = np.sort(t + draw(st.floats(0.0, 0.5)) * dt * np.random.default_rng(a).uniform(-1, 1, n))
    for _ in range(draw(st.integers(0, 3))):
        i = draw(st.integers(1, n - 2))
        t[i] = t[i - 1]
    command = draw(st.sampled_from(["as is", "zero", "constant", "mostly zero"]))
    if command == "zero":
        u[:] = 0.0
    elif command == "constant":
        u[:] = 0.3
    elif command == "mostly zero":
        u[: 3 * n // 4] = 0.0
    scale = draw(st.sampled_from([1.0, -1.0, 180 / math.pi, 0.5]))
    target = draw(st.sampled_from(["theta", "phi", "u"]))
    cols = {"theta": theta, "phi": phi, "u": u}
    cols[target] = cols[target] * scale
    return Recording(t=t, **cols)


def test_no_recording_shape_raises_anything_but_a_one_line_user_error(rig, base) -> None:
    @settings(max_examples=14, deadline=None, derandomize=True, suppress_health_check=list(HealthCheck))
    @given(recording_shapes(base))
    def check(rec: Recording) -> None:
        try:
            d = diagnose(rec, rig, FAST)
        except UserError as err:
            assert str(err) and "\n" not in str(err)
            return
        out = json.loads(json.dumps(d.to_json()))
        assert set(out) >= KEYS
        assert set(out["equations"]) == {"arm", "pendulum"}

    check()


@pytest.fixture(scope="module")
def dc_step(tmp_path_factory) -> tuple[Recording, object]:
    """A voltage step on a DC-motor rig shaped like the macstepien recordings (the arm at rest, then spinning): the
    command is constant while the arm moves, so the arm regression's input gain is not identified there."""
    case = next(c for c in suite.realistic_cases() if c.excitation == "single_step" and not c.held_out)
    return suite.generate_realistic(case, tmp_path_factory.mktemp("suite")), load_rig(case.shape)


@pytest.mark.parametrize(("column", "words"), [("u", "the sign of u appears reversed"),
                                               ("phi", "the sign of φ appears reversed"),
                                               ("theta", "the sign of θ appears reversed")])
def test_a_reversed_step_is_caught_by_the_command_s_work(dc_step, column, words) -> None:
    """Energy balance (eq. 4's E and friction that only dissipates): a step whose command does negative work on an
    arm that gains energy has u or φ reversed, and positive work tells a reversed θ (the pendulum row) from φ; as
    recorded, the same step passes the checks."""
    from furuta_rt.diagnose.regression.states import prepare
    from furuta_rt.diagnose.stages import conventions

    rec, rig = dc_step
    assert conventions.conventions(prepare(rec, rig), rig) is not None  # as recorded: no error
    bad = dataclasses.replace(rec, **{column: -getattr(rec, column)})
    with pytest.raises(UserError, match=words) as err:
        conventions.conventions(prepare(bad, rig), rig)
    assert "J of work on the arm" in str(err.value) and f"--map {column}.scale=-1" in str(err.value)
