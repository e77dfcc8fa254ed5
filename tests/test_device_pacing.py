"""hil_mock's real-time pacing: the busy wait before each tick covers the floor of the sleeps' measured overshoot.

Deterministic: a fake clock whose sleeps overshoot by a set amount stands in for the machine."""

from __future__ import annotations

import pytest

from hil_mock import timing
from hil_mock.timing import QUANTILE_STEP_S, SPIN_MARGIN_S, DeadlineWaiter


class FakeClock:
    """perf_counter advances 0.1 µs a read; a sleep lasts what was asked plus an overshoot: ``overshoot`` seconds, or
    the next of ``overshoots`` (cycled) when given."""

    def __init__(self, overshoot: float, overshoots: list[float] | None = None) -> None:
        self.now = 0.0
        self.overshoots = overshoots or [overshoot]
        self.sleeps = 0
        self.spun = 0.0  # time spent reading the clock (the busy wait)

    @property
    def overshoot(self) -> float:
        return self.overshoots[self.sleeps % len(self.overshoots)]

    def perf_counter(self) -> float:
        self.now += 1e-7
        self.spun += 1e-7
        return self.now

    def sleep(self, seconds: float) -> None:
        self.now += seconds + self.overshoot
        self.sleeps += 1


def run_ticks(waiter: DeadlineWaiter, clock: FakeClock, ticks: range) -> list[float]:
    """Wait for 1-ms deadlines ``ticks``; each tick's lateness."""
    late = []
    for k in ticks:
        deadline = k * 1e-3
        waiter.wait(deadline)
        late.append(clock.now - deadline)
    return late


@pytest.mark.parametrize("overshoot_us", [10.0, 40.0])
def test_a_steady_overshoot_is_covered_and_ticks_start_on_time(monkeypatch: pytest.MonkeyPatch,
                                                               overshoot_us: float) -> None:
    clock = FakeClock(overshoot_us * 1e-6)
    monkeypatch.setattr(timing, "time", clock)
    waiter = DeadlineWaiter(100e-6)
    assert waiter.spin_s == 0.0  # before any measurement: no spin
    late = run_ticks(waiter, clock, range(1, 600))
    assert waiter.spin_s == pytest.approx(overshoot_us * 1e-6 + SPIN_MARGIN_S, abs=2 * QUANTILE_STEP_S)
    assert min(late) >= 0.0 and max(late[-100:]) < 1e-6  # every tick at its deadline, never before
    clock.spun = 0.0
    run_ticks(waiter, clock, range(600, 700))
    assert clock.spun / 100 < SPIN_MARGIN_S + 2 * QUANTILE_STEP_S + 1e-6  # the margin's CPU, not the configured 100 µs


@pytest.mark.parametrize("upper_us", [80.0, 400.0])
def test_an_erratic_overshoot_is_covered_only_through_its_floor(monkeypatch: pytest.MonkeyPatch,
                                                                 upper_us: float) -> None:
    """Half the sleeps overshoot by 40 µs, the other half by 40 µs up to ``upper_us``: the spin covers the 40 µs every
    sleep overshoots (the steady half starts on time, the rest is late by the erratic part only, never more) at
    almost no CPU, where covering the erratic part — a capped 100-µs spin — burns ~30 µs a tick."""
    upper = [40e-6 + (upper_us - 40.0) * 1e-6 * ((7 * k) % 10) / 9 for k in range(20)]
    clock = FakeClock(0.0, [40e-6 if k % 2 == 0 else upper[k] for k in range(20)])
    monkeypatch.setattr(timing, "time", clock)
    waiter = DeadlineWaiter(100e-6)
    run_ticks(waiter, clock, range(1, 1000))
    assert waiter.floor_s == pytest.approx(40e-6, abs=2 * QUANTILE_STEP_S)
    clock.spun = 0.0
    late = run_ticks(waiter, clock, range(1000, 1200))
    assert clock.spun / 200 < SPIN_MARGIN_S + 2 * QUANTILE_STEP_S + 1e-6
    assert min(late) >= 0.0
    assert sum(x < 1e-6 for x in late) >= 100  # the steady half on time
    assert max(late) < (upper_us - 40.0) * 1e-6  # the floor is off every tick's lateness


def test_an_idle_wait_does_not_spin_and_a_zero_spin_never_spins(monkeypatch: pytest.MonkeyPatch) -> None:
    clock = FakeClock(30e-6)
    monkeypatch.setattr(timing, "time", clock)
    waiter = DeadlineWaiter(100e-6)
    waiter.wait(1e-3, spin=False)
    assert clock.now >= 1e-3 + 30e-6  # slept to the deadline
    assert waiter.floor_s == 0.0  # nothing learned
    none = DeadlineWaiter(0.0)
    for k in range(2, 50):
        none.wait(k * 1e-3)
    assert none.spin_s == 0.0
