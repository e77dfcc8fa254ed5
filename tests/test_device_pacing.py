"""hil_mock's real-time pacing: the busy wait before each tick follows the sleeps' measured overshoot.

Deterministic: a fake clock whose sleeps overshoot by a set amount stands in for the machine."""

from __future__ import annotations

import pytest

from hil_mock import timing
from hil_mock.timing import SPIN_MARGIN_S, DeadlineWaiter


class FakeClock:
    """perf_counter advances 0.1 µs a read; a sleep lasts what was asked plus ``overshoot``."""

    def __init__(self, overshoot: float) -> None:
        self.now = 0.0
        self.overshoot = overshoot
        self.spun = 0.0  # time spent reading the clock (the busy wait)

    def perf_counter(self) -> float:
        self.now += 1e-7
        self.spun += 1e-7
        return self.now

    def sleep(self, seconds: float) -> None:
        self.now += seconds + self.overshoot


@pytest.mark.parametrize("overshoot_us", [10.0, 40.0])
def test_the_spin_shrinks_to_the_sleeps_overshoot_and_ticks_stay_on_time(monkeypatch: pytest.MonkeyPatch,
                                                                          overshoot_us: float) -> None:
    clock = FakeClock(overshoot_us * 1e-6)
    monkeypatch.setattr(timing, "time", clock)
    waiter = DeadlineWaiter(100e-6)
    assert waiter.spin_s == pytest.approx(100e-6)  # before any measurement: the configured spin
    late = []
    for k in range(1, 400):
        deadline = k * 1e-3
        waiter.wait(deadline)
        late.append(clock.now - deadline)
    expected = 1.5 * overshoot_us * 1e-6 + SPIN_MARGIN_S
    assert waiter.spin_s == pytest.approx(expected, rel=0.02)
    assert min(late) >= 0.0 and max(late[-100:]) < 1e-6  # every tick at its deadline, never before
    clock.spun = 0.0
    for k in range(400, 500):
        waiter.wait(k * 1e-3)
    spin_per_tick = clock.spun / 100
    assert spin_per_tick == pytest.approx(expected - overshoot_us * 1e-6, abs=2e-6)  # not the configured 100 µs


def test_an_idle_wait_does_not_spin_and_a_zero_spin_never_spins(monkeypatch: pytest.MonkeyPatch) -> None:
    clock = FakeClock(30e-6)
    monkeypatch.setattr(timing, "time", clock)
    waiter = DeadlineWaiter(100e-6)
    waiter.wait(1e-3, spin=False)
    assert clock.now >= 1e-3 + 30e-6 and waiter.overshoot_s == 100e-6  # slept to the deadline, nothing learned
    none = DeadlineWaiter(0.0)
    for k in range(2, 50):
        none.wait(k * 1e-3)
    assert none.spin_s == 0.0
