"""The stick windows' error measure (furuta_rt.diagnose.stages.stickslip.cell_error): motion within one encoder count is no
error, exactly, whatever the unknown start position inside the first count."""

from __future__ import annotations

import numpy as np

from furuta_rt.diagnose.stages.stickslip import cell_error

LSB = 2 * np.pi / 4096


def brute(e: np.ndarray, lsb: float, n: int = 40001) -> float:
    shifts = np.linspace(-0.5, 0.5, n)[:, None] * lsb
    return float(np.min(np.sum(np.maximum(np.abs(e[None, :] + shifts) - 0.5 * lsb, 0.0) ** 2, axis=1)))


def test_a_trajectory_inside_one_count_is_no_error() -> None:
    # spans 0.97 of a count, off-centre: a grid of tenths over the start position left an error here
    e = (np.linspace(0.0, 0.97, 200) - 0.235) * LSB
    for shift in (0.0, -0.25, 0.2):
        assert cell_error(e + shift * LSB, LSB) <= 1e-12 * LSB**2  # zero up to the bisection's last step
    shifts = np.linspace(-0.5, 0.5, 11)[:, None] * LSB
    grid = np.min(np.sum(np.maximum(np.abs(e[None, :] + shifts) - 0.5 * LSB, 0.0) ** 2, axis=1))
    assert grid > 0.0


def test_the_start_position_stays_inside_its_count() -> None:
    # 2 counts away throughout: the best start shift is half a count, the rest is error
    e = np.full(50, 2.0 * LSB)
    assert np.isclose(cell_error(e, LSB), 50 * LSB**2, rtol=1e-9)
    assert np.isclose(cell_error(-e, LSB), 50 * LSB**2, rtol=1e-9)


def test_matches_a_dense_search() -> None:
    rng = np.random.default_rng(3)
    for _ in range(50):
        e = rng.normal(0.0, rng.uniform(0.2, 3.0), 80) * LSB + rng.uniform(-1, 1) * LSB
        ref = brute(e, LSB)
        got = cell_error(e, LSB)
        assert got <= ref * (1 + 1e-9) + 1e-30
        assert got >= ref * (1 - 1e-3) - 1e-14 * LSB**2
