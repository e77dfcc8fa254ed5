"""scripts/bench_trace: which 1 kHz misses the machine explains. The reduction of a kernel trace to the CPU's lost
time, and the attribution of miss windows to it, on trace text written here in trace_pipe's own format; then the
kernel's own tracer where root allows it (the reader must not load the CPU it traces)."""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path

import pytest

from scripts.bench_trace import TRACEFS, CpuTrace, attribute_windows, read_timeline, timeline_figures

CPU = 1
P = 1e-3  # the period, s


def switch(t: float, prev: tuple[str, int, int, str], nxt: tuple[str, int, int]) -> str:
    (pc, pp, pprio, state), (nc, np_, nprio) = prev, nxt
    by = "<idle>" if pp == 0 else pc
    return (f"          {by}-{pp}   [{CPU:03d}] d..2. {t:.6f}: sched_switch: prev_comm={pc} prev_pid={pp} "
            f"prev_prio={pprio} prev_state={state} ==> next_comm={nc} next_pid={np_} next_prio={nprio}")


def waking(t: float, comm: str, pid: int, by: str = "<idle>-0", target: int = CPU, cpu: int = CPU) -> str:
    """``by``: the task running when the wake-up was recorded (the idle task: from an interrupt)."""
    return f"          {by}   [{cpu:03d}] d.h3. {t:.6f}: sched_waking: comm={comm} pid={pid} prio=120 target_cpu={target:03d}"


def charged(t: float, comm: str, pid: int, ns: int) -> str:
    return f"          {comm}-{pid}   [{CPU:03d}] d..2. {t:.6f}: sched_stat_runtime: comm={comm} pid={pid} runtime={ns} [ns]"


IDLE = ("swapper/1", 0, 120)
LOOP = ("python", 100, 49)
KWORKER = ("kworker/u10:0", 200, 120)
HOG = ("hog", 300, 120)


def woken(t: float, t_on: float, who: tuple[str, int, int], explicit: bool) -> list[str]:
    """A task woken on the idle CPU at ``t`` and on it from ``t_on``. This kernel records no switch out of the idle
    task (``explicit`` False): the task's own events show it ran."""
    return [waking(t, who[0], who[1]), *([switch(t_on, ("swapper/1", 0, 120, "R"), who)] if explicit else [])]


def tick(t: float, explicit: bool, us: float = 20.0) -> list[str]:
    """An ordinary round trip: the loop woken, on the CPU within 2 µs, charged all of its ``us``, then idle."""
    end = t + 2e-6 + us * 1e-6
    return [*woken(t, t + 2e-6, LOOP, explicit), charged(end, "python", 100, round(us * 1000)),
            switch(end + 1e-6, ("python", 100, 49, "S"), IDLE)]


def lines(explicit: bool) -> list[str]:
    out: list[str] = []
    for k in range(10):  # 0.000 … 0.009: ordinary ticks
        out += tick(k * P, explicit)
    # 0.010: the loop is woken on the idle CPU and runs only 800 µs later — nothing ran it
    out += [*woken(0.010, 0.0108, LOOP, explicit), charged(0.010820, "python", 100, 20_000),
            switch(0.010821, ("python", 100, 49, "S"), IDLE)]
    # 0.020: the loop holds the CPU 900 µs and is charged 300 µs — the CPU stopped under it
    out += [*woken(0.020, 0.020002, LOOP, explicit), charged(0.020902, "python", 100, 300_000),
            switch(0.020903, ("python", 100, 49, "S"), IDLE)]
    # 0.030: the kworker is woken while a hog runs, charged in full for 700 µs — load, not the machine
    out += [*woken(0.029990, 0.029991, HOG, explicit), waking(0.030000, "kworker/u10:0", 200, by="hog-300"),
            charged(0.030700, "hog", 300, 709_000), switch(0.030701, ("hog", 300, 120, "R"), KWORKER),
            charged(0.030710, "kworker/u10:0", 200, 9_000), switch(0.030711, ("kworker/u10:0", 200, 120, "I"), HOG),
            charged(0.030720, "hog", 300, 10_000), switch(0.030721, ("hog", 300, 120, "S"), IDLE)]
    # a wake-up aimed at the other CPU, and another CPU's events, say nothing about this one
    out += [waking(0.031, "other", 400, target=0), waking(0.0315, "python", 100, cpu=0)]
    # then nothing at all until 0.042: not around the deadline at 0.040 either (its timer could not fire)
    for k in (42, 43):
        out += tick(k * P, explicit)
    return out


@pytest.fixture(params=[False, True], ids=["as this kernel writes it", "with switches out of idle"])
def trace(tmp_path: Path, request: pytest.FixtureRequest) -> Path:
    path = tmp_path / "trace.txt"
    path.write_text("\n".join(lines(request.param)) + "\n")
    return path


def test_the_lost_time_is_found_and_told_apart_from_load(trace: Path) -> None:
    tl = read_timeline(trace, CPU)
    # the ends are the first event after the loss: the loop's first charge, or its switch in where one is written
    assert tl.lost.ravel().tolist() == pytest.approx([0.010, 0.0108, 0.020, 0.020902], abs=25e-6)
    [(a, b, who)] = tl.held
    assert (a, b, who) == (pytest.approx(0.030), pytest.approx(0.030701), "hog (prio 120)")
    figures = timeline_figures(tl, (0.0, 0.05))
    assert figures["lost_stretches"] == 2
    assert figures["lost_total_ms"] == pytest.approx(0.8 + 0.9, abs=0.03)


def test_misses_are_the_machines_only_where_it_lost_time(trace: Path) -> None:
    tl = read_timeline(trace, CPU)
    windows = [(0.010, 0.011, 1),  # nothing ran the woken loop
               (0.020, 0.021, 1),  # the CPU stopped under it
               (0.030, 0.031, 1),  # behind the hog: unexplained, the hog named
               (0.040, 0.041, 2),  # across the silent deadline at 0.040: two periods
               (0.005, 0.006, 1)]  # an ordinary stretch: unexplained, nobody to name
    r = attribute_windows(windows, tl, P)
    assert r["machine_by_kind"] == {"cpu_not_running": 2, "at_a_deadline": 2}
    assert (r["misses"], r["machine"], r["unexplained"]) == (6, 4, 2)
    assert r["unexplained_behind_another_task"] == {"hog (prio 120)": 1}


def test_a_task_charged_for_its_time_is_not_lost_time(tmp_path: Path) -> None:
    """The loop woken on the idle CPU computes 700 µs with no event in between, charged for all of it: the CPU ran."""
    path = tmp_path / "trace.txt"
    path.write_text("\n".join([*tick(0.0, False, us=700.0), *tick(0.002, False)]) + "\n")
    assert read_timeline(path, CPU).lost.size == 0


def test_a_deadline_is_silent_only_on_an_idle_cpu(tmp_path: Path) -> None:
    """Nothing recorded across a deadline is the machine's only if the CPU was idle: a task of ours that computes
    through it, charged for the time, records nothing either, and that miss stays unexplained."""
    path = tmp_path / "trace.txt"
    path.write_text("\n".join([*tick(0.0098, False, us=700.0), *tick(0.01095, False)]) + "\n")
    r = attribute_windows([(0.010, 0.011, 1)], read_timeline(path, CPU), P)
    assert (r["machine"], r["unexplained"]) == (0, 1)
    path.write_text("\n".join([*tick(0.0098, False, us=20.0), *tick(0.01095, False)]) + "\n")  # idle through it
    r = attribute_windows([(0.010, 0.011, 1)], read_timeline(path, CPU), P)
    assert r["machine_by_kind"]["at_a_deadline"] == 1


def test_going_idle_ends_every_wait(tmp_path: Path) -> None:
    """A task woken onto the CPU that then ran elsewhere must not make later idle stretches lost time: the CPU goes
    idle only when nothing is left to run on it."""
    out = [*woken(0.0, 2e-6, LOOP, False), waking(0.00001, "moved", 500, by="python-100"),
           charged(0.00002, "python", 100, 18_000), switch(0.000021, ("python", 100, 49, "S"), IDLE),
           waking(0.005, "python", 100), waking(0.0056, "python", 101)]
    path = tmp_path / "trace.txt"
    path.write_text("\n".join(out) + "\n")
    assert read_timeline(path, CPU).lost.ravel().tolist() == pytest.approx([0.005, 0.0056])  # the loop's wait only


@pytest.mark.skipif(not os.access(TRACEFS / "instances", os.W_OK) or len(os.sched_getaffinity(0)) < 2,
                    reason="needs root, tracefs and two CPUs: the kernel's own tracer")
def test_the_reader_does_not_wake_itself_on_the_traced_cpu(tmp_path: Path) -> None:
    """A thread on the traced CPU sleeps and wakes at 1 kHz while the trace runs. The trace holds its wake-ups, and
    no wake-up of the reader raised on that CPU: a reader that waited on trace_pipe would be woken there by every
    event, and each wake-up is itself an event (thousands a second)."""
    cpu = max(os.sched_getaffinity(0))
    path = tmp_path / "trace.txt"
    stop = threading.Event()
    ids: dict[str, int] = {}

    def ticking() -> None:
        os.sched_setaffinity(0, {cpu})
        ids["ticker"] = threading.get_native_id()
        while not stop.is_set():
            time.sleep(1e-3)

    ticker = threading.Thread(target=ticking)
    with CpuTrace(cpu, path) as tracer:
        assert tracer.ok, tracer.why
        ids["reader"] = tracer._reader.native_id  # type: ignore[union-attr]
        ticker.start()
        time.sleep(0.5)
        stop.set()
        ticker.join()
    text = path.read_text()
    assert not (TRACEFS / "instances" / "furuta-bench").exists()
    woken = text.count(f"sched_waking: comm=python pid={ids['ticker']} ")
    assert woken >= 100, woken  # 0.5 s of 1 kHz sleeps, under any load
    reader_wakeups = sum(1 for line in text.splitlines()
                         if f"[{cpu:03d}]" in line and f"sched_waking: comm=python pid={ids['reader']} " in line)
    assert reader_wakeups <= 5, reader_wakeups
