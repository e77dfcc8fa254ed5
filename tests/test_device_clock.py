"""The device's clock, through the daemon's own host path (SerialHardware + ControlLoop on a pty, a scripted
device writing SAMPLE frames: tests/test_reliability_harness.py): `--duration` is device time, not a tick
count; a clock that goes back within a session is a fault (trip, u = 0), not a negative run time; a device
that never sent a SAMPLE is not said to have stopped "after seq 0"."""

from __future__ import annotations

import pytest
from test_reliability_harness import run_host_loop

import firmware_protocol as fp

RATE = 500


def _sample(seq: int, t_us: int) -> bytes:
    return fp.encode(fp.Sample(seq, t_us, 20, 0, 0, 0))  # θ ≈ 2 mrad: arms and balances


@pytest.mark.parametrize(("step_us", "ticks"), [(200, 991), (2000, 100), (4000, 51)],
                         ids=["10x fast", "nominal", "2x slow"])
def test_the_duration_is_device_time_not_ticks(step_us: int, ticks: int) -> None:
    """0.2 s of device time at 500 Hz: the run's ticks cover [0, 0.2 s) of the device clock, the last one
    the first SAMPLE stamped at least 0.2 s - one period (2 ms) after the first: at 2 ms steps 100 ticks (as a
    tick count would say); stamped 0.2 ms apart (a device 10x fast) 991, not 100 (0.02 s of device time); 4 ms
    apart 51, not 100 (0.4 s)."""
    pieces = [b"\x00"] + [_sample(s, s * step_us) for s in range(ticks + 200)]
    result, _, dev, _ = run_host_loop(pieces, link_timeout_s=1.0, rate=RATE, duration=0.2)
    assert result.end == "duration", result.trip_message
    assert result.ticks == ticks
    assert 0.198 - 1e-9 <= result.device_span_s < 0.198 + step_us * 1e-6
    assert dev.output_zero


def test_a_device_clock_that_goes_back_trips_with_u_zero() -> None:
    back_at = 300
    pieces = [b"\x00"] + [_sample(s, s * 2000 if s < back_at else (s - back_at) * 2000 + 1000) for s in range(600)]
    result, _, dev, _ = run_host_loop(pieces, link_timeout_s=1.0, rate=RATE, duration=5.0)
    assert result.end == "trip" and result.trip_reason == "sequence", result.trip_message
    assert "clock went back" in result.trip_message and f"seq {back_at}" in result.trip_message
    assert result.device_span_s >= 0
    answered = [c.seq for c in dev.commands if c.flags & fp.CommandFlags.ENABLE]
    assert max(answered) < back_at, "no ENABLE COMMAND answers a SAMPLE of the clock that went back"
    assert dev.output_zero


def test_no_sample_at_all_is_not_called_after_seq_0() -> None:
    result, _, _, _ = run_host_loop([b"\x00"], link_timeout_s=0.05, rate=RATE, duration=1.0, first_sample_timeout=0.3)
    assert result.end == "trip" and result.trip_reason == "link_loss"
    assert "after seq" not in result.trip_message and "no SAMPLE" in result.trip_message, result.trip_message
